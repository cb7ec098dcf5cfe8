"""Collision-free shortest paths on an occupancy grid, for a round robot of a given radius.

Paths are planned on planning cells of about ``PLANNING_CELL_M`` (blocks of map cells, all
walkable): a robot needs no finer steps, and Dijkstra runs on a quarter of the nodes of a
0.05 m map. The graph is the largest 4-connected region of planning cells, each joined to
its 8 neighbours (a diagonal step needs both cells it cuts past). A cell's cost per metre
grows near walls, so paths keep to the middle of doors and corridors, and jumps where the
robot's radius does not fit: a narrower door is still used when it is the only way in, and
a room is unreachable only when no free path leads there. Shortest paths are Dijkstra's
(scipy.sparse.csgraph), then pulled straight where a straight segment keeps at least the
clearance the grid path had.

Invariants:
    1. Every path cell and every point of a pulled segment lies in walkable map cells.
    2. ``cells``, ``node`` and ``clearance_m`` speak planning cells; ``map_cells`` converts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from lessmap.floorplan.grid import FloorplanError, OccupancyGrid

__all__ = ["PLANNING_CELL_M", "Planner", "build_planner", "walkable_cells"]

#: Side of a planning cell, rounded to a whole number of map cells.
PLANNING_CELL_M = 0.1

#: Cost per metre where the robot's radius does not fit: a detour up to this many times
#: longer is preferred to a door narrower than the robot.
TIGHT_COST = 25.0
#: Beyond the robot's radius, this much more clearance is "comfortable" (cost 1 a metre);
#: closer, the cost rises linearly to 2.
COMFORT_M = 0.4
_NEIGHBOURS = ((0, 1), (1, 0), (1, 1), (1, -1))  # the other four are the same edges reversed


def walkable_cells(free: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The largest 4-connected region of free cells: where robots walk.

    Raises:
        FloorplanError: no free cell.
    """
    labels, count = ndimage.label(free)
    if count == 0:
        msg = "the map has no free cell"
        raise FloorplanError(msg)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return np.asarray(labels == int(sizes.argmax()))


@dataclass(frozen=True, slots=True, kw_only=True)
class Planner:
    """The graph of the walkable planning cells, and what a path needs to be measured."""

    shape: tuple[int, int]  # planning cells
    factor: int  # map cells along a planning cell's side
    walkable: NDArray[np.bool_]  # (rows, cols) planning cells in the graph
    node_of_cell: NDArray[np.int64]  # (rows * cols,), -1 where not walkable
    cell_of_node: NDArray[np.int64]  # (nodes,), flat cell index
    clearance_m: NDArray[np.float64]  # (rows, cols): least distance to an occupied map cell
    graph: sparse.csr_array  # directed, both ways; weights: metres times cost
    robot_radius_m: float
    resolution_m: float  # side of a planning cell

    def map_cells(self, cells: NDArray[np.float64]) -> NDArray[np.float64]:
        """Planning cells (fractional allowed), (n, 2), as fractional map cells: the centres."""
        return np.asarray(cells, dtype=np.float64) * self.factor + (self.factor - 1) / 2.0

    def coarse(self, labels: NDArray[np.int32]) -> NDArray[np.int32]:
        """A map-cell label image sampled at the planning cells' centres, 0 off the graph."""
        rows, cols = self.shape
        pad = ((0, rows * self.factor - labels.shape[0]), (0, cols * self.factor - labels.shape[1]))
        half = self.factor // 2
        sampled = np.pad(labels, pad)[half :: self.factor, half :: self.factor]
        return np.where(self.walkable, sampled, 0).astype(np.int32)

    def node(self, row: int, col: int) -> int:
        """The node of a walkable cell (-1 when not walkable)."""
        return int(self.node_of_cell[row * self.shape[1] + col])

    def cells(self, nodes: NDArray[np.int64]) -> NDArray[np.int64]:
        """(row, col) of nodes, shape (n, 2)."""
        flat = self.cell_of_node[nodes]
        return np.stack([flat // self.shape[1], flat % self.shape[1]], axis=-1)

    def costs_from(
        self, source: int, limit: float = np.inf
    ) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
        """Path costs from ``source`` to every node (inf beyond ``limit``), and predecessors."""
        dist, pred = csgraph.dijkstra(
            self.graph, directed=True, indices=[source], return_predecessors=True, limit=limit
        )
        return np.asarray(dist[0]), np.asarray(pred[0], dtype=np.int32)

    def path(self, pred: NDArray[np.int32], source: int, goal: int) -> NDArray[np.int64]:
        """Nodes from ``source`` to ``goal`` along a predecessor tree of ``costs_from``.

        Raises:
            FloorplanError: ``goal`` is not reached from ``source``.
        """
        nodes = [goal]
        while nodes[-1] != source:
            previous = int(pred[nodes[-1]])
            if previous < 0:
                msg = f"no path from node {source} to node {goal}"
                raise FloorplanError(msg)
            nodes.append(previous)
        return np.asarray(nodes[::-1], dtype=np.int64)

    def pulled(self, nodes: NDArray[np.int64]) -> NDArray[np.float64]:
        """Corners of a path after pulling it straight, as fractional cells (row, col), (k, 2).

        A segment replaces a stretch of the grid path when every point of it is walkable
        with at least the smaller of the robot's radius and the stretch's own clearance.
        """
        cells = self.cells(nodes).astype(np.float64)
        clear = self.clearance_m.ravel()[self.cell_of_node[nodes]]
        corners = [0]
        last = len(cells) - 1
        while corners[-1] < last:
            i = corners[-1]
            ok, step = i + 1, 1
            while ok + step <= last and self._straight(cells, clear, i, ok + step):
                ok += step
                step *= 2
            bad = min(ok + step, last + 1)
            while bad - ok > 1:  # the last straight end lies in [ok, bad)
                mid = (ok + bad) // 2
                if self._straight(cells, clear, i, mid):
                    ok = mid
                else:
                    bad = mid
            corners.append(ok)
        return cells[corners]

    def _straight(
        self, cells: NDArray[np.float64], clear: NDArray[np.float64], i: int, j: int
    ) -> bool:
        need = min(self.robot_radius_m, float(clear[i : j + 1].min()))
        count = max(2, int(np.ceil(2.0 * np.hypot(*(cells[j] - cells[i])))) + 1)
        t = np.linspace(0.0, 1.0, count)[:, None]
        points = np.rint(cells[i] + t * (cells[j] - cells[i])).astype(np.int64)
        flat = points[:, 0] * self.shape[1] + points[:, 1]
        if (self.node_of_cell[flat] < 0).any():
            return False
        return bool((self.clearance_m.ravel()[flat] >= need - 1e-9).all())


def build_planner(
    grid: OccupancyGrid,
    walkable: NDArray[np.bool_],
    robot_radius_m: float,
    cell_m: float = PLANNING_CELL_M,
) -> Planner:
    """The planning graph of ``walkable`` for a robot of ``robot_radius_m`` (module docstring).

    Raises:
        FloorplanError: the radius is negative, or no planning cell is walkable.
    """
    if not robot_radius_m >= 0:
        msg = f"robot radius must be at least 0 m, got {robot_radius_m}"
        raise FloorplanError(msg)
    factor = max(1, round(cell_m / grid.resolution_m))
    res = grid.resolution_m * factor
    fine_clearance = ndimage.distance_transform_edt(grid.free) * grid.resolution_m
    rows, cols = (-(-n // factor) for n in grid.shape)
    pad = ((0, rows * factor - grid.shape[0]), (0, cols * factor - grid.shape[1]))
    blocks = (rows, factor, cols, factor)
    inside = np.asarray(np.pad(walkable, pad).reshape(blocks).all(axis=(1, 3)))
    if not inside.any():
        msg = "no walkable space wider than a planning cell"
        raise FloorplanError(msg)
    inside = walkable_cells(inside)
    clearance = np.pad(fine_clearance, pad).reshape(blocks).min(axis=(1, 3))
    cost = 1.0 + np.clip((robot_radius_m + COMFORT_M - clearance) / COMFORT_M, 0.0, 1.0)
    cost[clearance < robot_radius_m] = TIGHT_COST
    node_of_cell = np.full(rows * cols, -1, dtype=np.int64)
    cell_of_node = np.flatnonzero(inside.ravel())
    node_of_cell[cell_of_node] = np.arange(len(cell_of_node))
    nodes = node_of_cell.reshape(rows, cols)
    heads, tails, weights = [], [], []
    for dr, dc in _NEIGHBOURS:
        cols_a = slice(max(0, -dc), cols - max(0, dc))
        cols_b = slice(max(0, dc), cols - max(0, -dc))
        a = (slice(0, rows - dr), cols_a)
        b = (slice(dr, rows), cols_b)
        both = inside[a] & inside[b]
        if dr and dc:  # a diagonal step must not cut past a cell off the graph
            both &= inside[slice(0, rows - dr), cols_b] & inside[slice(dr, rows), cols_a]
        length_m = res * float(np.hypot(dr, dc))
        heads.append(nodes[a][both])
        tails.append(nodes[b][both])
        weights.append(length_m * 0.5 * (cost[a][both] + cost[b][both]))
    head = np.concatenate(heads)
    tail = np.concatenate(tails)
    weight = np.concatenate(weights)
    count = len(cell_of_node)
    graph = sparse.csr_array(
        (
            np.concatenate([weight, weight]),
            (np.concatenate([head, tail]), np.concatenate([tail, head])),
        ),
        shape=(count, count),
    )
    # csgraph works on 32-bit indices: convert once here, not on every search.
    graph.indices = graph.indices.astype(np.int32)
    graph.indptr = graph.indptr.astype(np.int32)
    return Planner(
        shape=(rows, cols),
        factor=factor,
        walkable=inside,
        node_of_cell=node_of_cell,
        cell_of_node=cell_of_node,
        clearance_m=clearance,
        graph=graph,
        robot_radius_m=robot_radius_m,
        resolution_m=res,
    )

"""A room map: each free cell of a grid labelled by the area of the robot poses it is nearest.

Input: the grid and each pose with its area; output: int32 labels of the grid's shape, 0 none
(and furniture by rule 6).

1. **Nearest pose.** A free cell takes the area of the pose nearest by a walk over free cells
   (8-neighbours, diagonals √2), so a wall is never crossed; poses in one cell vote.
2. **Reach.** Cells beyond ``max_distance_m`` of walk from every pose stay 0; a pose on an
   occupied cell moves to the nearest free cell within ``snap_m``, else is dropped.
3. **Doorways.** Free space is cut into regions at passages narrower than ``door_width_m``
   (cores: cells over half a door from walls, each cell joining its nearest); an obstacle
   joined to no wall and at most ``furniture_max_m`` long is furniture, never one side of a
   doorway (``lessmap.floorplan.furniture``). A region with no pose stays 0 (seen, not
   visited); one an area holds ``region_share`` of goes to it whole (a late decision
   paints nothing). What no area holds is cut again at each of the ``wider_passages_m``
   in turn (openings), where ``opening_share`` decides. What is still shared goes to the
   region's largest area (``region_plurality``): no passage offers a place to cut it, so a
   corridor the stream named anew on every pass is still one room.
4. **Fleet.** Areas of two robots are one room when, on the cells within ``merge_m`` of both
   robots' poses, one holds half of the other's; then rules 1-3 over all poses.
5. **A room stops at a doorway.** An area's cells in two doorway regions are two rooms: a
   change the stream missed (a dip into an office) or a wrong revisit would join them
   (``split_at_doorways``). So are its cells on two sides of an opening narrower than
   ``room_opening_m`` where the part beyond holds ``min_room_m2`` (``opening_parts``,
   ``split_at_openings``).
6. **Furniture is floor.** A piece of furniture whose free cells around name one room takes
   that room (``furniture_rooms``; ``FurniturePieces``): what a cleaning robot cannot reach
   under a desk is still the office.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from lessmap.floorplan.furniture import FurniturePieces, furniture
from lessmap.floorplan.pairs import unique_pairs

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from lessmap.floorplan.grid import OccupancyGrid

__all__ = [
    "PassageRegions",
    "RoomMapParams",
    "SampleField",
    "door_regions",
    "fleet_room_map",
    "label_cells",
    "merge_overlapping",
    "merged_room_map",
    "nearest_samples",
    "opening_parts",
    "passage_regions",
    "room_map",
    "split_at_doorways",
    "split_at_openings",
]

SQRT2 = float(np.sqrt(2.0))


@dataclass(frozen=True, slots=True, kw_only=True)
class RoomMapParams:
    """How far labels spread and where they stop (rules in the module docstring)."""

    max_distance_m: float = 8.0  # rule 2: about a room's depth seen from its middle
    snap_m: float = 0.5  # rule 2: a pose this near a wall still counts
    door_width_m: float = 1.2  # rules 3, 5: passages narrower than this split regions; 0: off
    # rules 3, 5: a free-standing obstacle up to this long (a desk, a chair) never makes a
    # doorway, or furniture would cut rooms in two; walls standing free are longer. 0: off
    furniture_max_m: float = 1.5
    # rule 5; off for maps whose furniture narrows rooms below a door (it would cut them)
    split_at_doorways: bool = True
    # rule 3: wide openings are tried only where doorways left two areas sharing a region
    wider_passages_m: tuple[float, ...] = (1.6, 2.0, 2.5, 3.0)
    # rule 5 also at openings this narrow (0: doorways only): an office open on its
    # corridor is a room of its own, even where the stream did not cut at its door
    room_opening_m: float = 2.0
    min_room_m2: float = 4.0  # rule 5 at openings: a smaller part beyond is a nook, not a room
    region_share: float = 0.6  # rule 3: the share of a doorway region one area must hold
    opening_share: float = 0.5  # rule 3: the same at the wider passages: the majority
    # rule 3: what no passage decided goes to its doorway region's largest area; off, it
    # keeps rule 1's labels (a corridor walked between rooms is then one piece a pass)
    region_plurality: bool = True
    merge_m: float = 1.5  # rule 4: cells this near a robot's poses show where its areas are
    # rule 6: the floor under furniture is the room's (the benchmark's ground truth counts it)
    furniture_rooms: bool = True

    def __post_init__(self) -> None:
        if not (self.max_distance_m > 0 and self.merge_m > 0):
            msg = "max_distance_m and merge_m must be > 0"
            raise ValueError(msg)
        if not (self.snap_m >= 0 and self.door_width_m >= 0 and self.furniture_max_m >= 0):
            msg = "snap_m, door_width_m and furniture_max_m must be >= 0"
            raise ValueError(msg)
        if any(w <= 0 for w in self.wider_passages_m):
            msg = f"wider_passages_m must all be > 0, got {self.wider_passages_m}"
            raise ValueError(msg)
        if not (self.room_opening_m >= 0 and self.min_room_m2 >= 0):
            msg = "room_opening_m and min_room_m2 must be >= 0"
            raise ValueError(msg)
        for name, share in (
            ("region_share", self.region_share),
            ("opening_share", self.opening_share),
        ):
            if not 0.5 <= share <= 1.0:
                msg = f"{name} must be in [0.5, 1], got {share}"
                raise ValueError(msg)

    @property
    def passage_widths_m(self) -> tuple[float, ...]:
        """Rule 3's widths in order: the doorway, then the wider passages above it."""
        if self.door_width_m <= 0:
            return ()
        wider = sorted(w for w in self.wider_passages_m if w > self.door_width_m)
        return (self.door_width_m, *wider)

    @property
    def splits_at_openings(self) -> bool:
        """Whether rule 5 applies at ``room_opening_m`` as well as at doorways."""
        return self.split_at_doorways and 0 < self.door_width_m < self.room_opening_m


@dataclass(frozen=True, slots=True)
class SampleField:
    """For every cell, which trajectory cell is geodesically nearest (rules 1 and 2).

    Computed once per trajectory: any labelling of its samples (one per method) is then a
    lookup, ``label_cells``.
    """

    source_of_cell: NDArray[np.int64]  # (rows, cols): index into source_cells, -1 = none
    distance_m: NDArray[np.float64]  # (rows, cols): walk to the nearest source, inf = none
    source_cells: NDArray[np.int64]  # (m,) flat indices of the cells holding samples
    sample_source: NDArray[np.int64]  # (n,) each sample's index into source_cells, -1 dropped
    resolution_m: float  # the grid's, for rules given in metres


def _free_graph(free: NDArray[np.bool_]) -> tuple[sparse.csr_array, NDArray[np.int64]]:
    """The 8-connected graph of the free cells, and each cell's node (-1 when occupied)."""
    rows, cols = free.shape
    node = np.full(free.shape, -1, dtype=np.int64)
    count = int(free.sum())
    node[free] = np.arange(count, dtype=np.int64)
    heads, tails, weights = [], [], []
    for dr, dc, weight in ((0, 1, 1.0), (1, 0, 1.0), (1, 1, SQRT2), (1, -1, SQRT2)):
        a = node[0 : rows - dr, max(0, -dc) : cols - max(0, dc)]
        b = node[dr:rows, max(0, dc) : cols + min(0, dc)]
        both = (a >= 0) & (b >= 0)
        heads.append(a[both])
        tails.append(b[both])
        weights.append(np.full(int(both.sum()), weight))
    graph = sparse.csr_array(
        (np.concatenate(weights), (np.concatenate(heads), np.concatenate(tails))),
        shape=(count, count),
    )
    return graph, node


def _nearest(
    graph: sparse.csr_array, node: NDArray[np.int64], seeds: NDArray[np.int64], limit: float
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Per cell, the nearest seed (index into ``seeds``) and its distance in cells.

    Cells beyond ``limit`` or not connected get -1 and inf.
    """
    out = np.full(node.shape, -1, dtype=np.int64)
    distance = np.full(node.shape, np.inf)
    if seeds.size == 0:
        return out, distance
    node_distance, _, nearest_node = csgraph.dijkstra(
        graph, directed=False, indices=seeds, min_only=True, return_predecessors=True, limit=limit
    )
    position = np.full(graph.shape[0], -1, dtype=np.int64)
    position[seeds] = np.arange(seeds.size, dtype=np.int64)
    reached = nearest_node >= 0
    free = node >= 0
    cell_seed = np.full(graph.shape[0], -1, dtype=np.int64)
    cell_seed[reached] = position[nearest_node[reached]]
    out[free] = cell_seed[node[free]]
    distance[free] = node_distance[node[free]]
    return out, distance


def nearest_samples(
    grid: OccupancyGrid, xy: NDArray[np.float64], params: RoomMapParams | None = None
) -> SampleField:
    """Find each free cell's nearest trajectory cell, walking free space (rules 1-2).

    Args:
        grid: the occupancy grid.
        xy: sample positions in metres, shape (n, 2), in the grid's frame.
        params: reach and snapping; default ``RoomMapParams()``.
    """
    params = params or RoomMapParams()
    free = grid.free
    cells = grid.xy_to_cell(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    rows, cols = grid.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < rows) & (cells[:, 1] >= 0) & (cells[:, 1] < cols)
    flat = np.full(len(cells), -1, dtype=np.int64)
    flat[inside] = cells[inside, 0] * cols + cells[inside, 1]
    # rule 2: a sample in a wall moves to the nearest free cell, if that is near enough
    clearance, (near_r, near_c) = ndimage.distance_transform_edt(~free, return_indices=True)
    snap_cells = params.snap_m / grid.resolution_m
    ok = inside.copy()
    ok[inside] = clearance.ravel()[flat[inside]] <= snap_cells
    flat[ok] = near_r.ravel()[flat[ok]] * cols + near_c.ravel()[flat[ok]]
    flat[~ok] = -1
    source_cells, sample_source = np.unique(flat[ok], return_inverse=True)
    sample_index = np.full(len(flat), -1, dtype=np.int64)
    sample_index[ok] = sample_source
    graph, node = _free_graph(free)
    seeds = node.ravel()[source_cells]
    limit = params.max_distance_m / grid.resolution_m
    source_of_cell, distance = _nearest(graph, node, seeds, limit)
    return SampleField(
        source_of_cell=source_of_cell,
        distance_m=distance * grid.resolution_m,
        source_cells=source_cells.astype(np.int64),
        sample_source=sample_index,
        resolution_m=grid.resolution_m,
    )


def label_cells(field: SampleField, labels: NDArray[np.int64]) -> NDArray[np.int32]:
    """Rule 1: each cell takes the area of its nearest samples (majority, ties to the smaller).

    Args:
        field: from ``nearest_samples``.
        labels: each sample's area, >= 1, shape (n,) as the samples given there.
    """
    labels = np.asarray(labels, dtype=np.int64)
    if labels.shape != field.sample_source.shape:
        msg = f"{labels.size} labels for {field.sample_source.size} samples"
        raise ValueError(msg)
    if labels.size and labels.min() < 1:
        msg = f"area labels must be >= 1, got {int(labels.min())}"
        raise ValueError(msg)
    kept = field.sample_source >= 0
    source_label = np.zeros(field.source_cells.size, dtype=np.int64)
    if kept.any():
        # count (source, label) pairs; per source the label with most samples, smaller on ties
        unique, counts, _ = unique_pairs(field.sample_source[kept], labels[kept])
        order = np.lexsort((unique[:, 1], -counts, unique[:, 0]))
        first = np.unique(unique[order, 0], return_index=True)[1]
        best = unique[order][first]
        source_label[best[:, 0]] = best[:, 1]
    out = np.zeros(field.source_of_cell.shape, dtype=np.int32)
    reached = field.source_of_cell >= 0
    out[reached] = source_label[field.source_of_cell[reached]]
    return out


@dataclass(frozen=True, slots=True)
class _Floor:
    """What rules 3 and 5 cut, whatever the width: free cells and furniture (one per map)."""

    grid: OccupancyGrid
    walkable: NDArray[np.bool_]  # free cells and furniture
    clearance_m: NDArray[np.float64]  # to the nearest wall
    graph: sparse.csr_array  # the walkable cells, 8-connected
    node: NDArray[np.int64]

    @classmethod
    def of(cls, grid: OccupancyGrid, furniture_cells: NDArray[np.bool_]) -> _Floor:
        walkable = grid.free | furniture_cells
        clearance = ndimage.distance_transform_edt(walkable) * grid.resolution_m
        graph, node = _free_graph(walkable)
        return cls(grid, walkable, clearance, graph, node)

    def cores(self, width_m: float) -> tuple[NDArray[np.int32], NDArray[np.int64]]:
        """Cells over half ``width_m`` from walls, labelled 8-connected; their flat indices."""
        cores, _ = ndimage.label(self.clearance_m > width_m / 2, structure=np.ones((3, 3)))
        return cores.astype(np.int32), np.flatnonzero(cores.ravel() > 0).astype(np.int64)

    def nearest_core(
        self, cores: NDArray[np.int32], core_cells: NDArray[np.int64], reach_m: float = np.inf
    ) -> NDArray[np.int64]:
        """Per cell, the core nearest by walking within ``reach_m``; 0 for none."""
        out = np.zeros(self.walkable.shape, dtype=np.int64)
        if core_cells.size == 0:
            return out
        limit = reach_m / self.grid.resolution_m
        nearest, _ = _nearest(self.graph, self.node, self.node.ravel()[core_cells], limit)
        reached = nearest >= 0
        out[reached] = cores.ravel()[core_cells[nearest[reached]]]
        return out


def door_regions(
    grid: OccupancyGrid, door_width_m: float, furniture_max_m: float = 0.0
) -> NDArray[np.int32]:
    """Rule 3's regions: free space cut at passages narrower than ``door_width_m``.

    Obstacles that ``furniture`` names (up to ``furniture_max_m`` long) count as free
    here: a chair in a room narrows no doorway. Returns an int32 array of the grid's
    shape: 0 on occupied cells (furniture too) and on free cells no core reaches, regions
    1..k otherwise.
    """
    return _door_regions(_Floor.of(grid, furniture(grid, furniture_max_m)), door_width_m)


def _door_regions(floor: _Floor, width_m: float) -> NDArray[np.int32]:
    regions = floor.nearest_core(*floor.cores(width_m))
    regions[~floor.grid.free] = 0
    return regions.astype(np.int32)


@dataclass(frozen=True, slots=True)
class PassageRegions:
    """Rule 3's regions at each passage width, doorways first, and rule 5's opening parts."""

    widths_m: tuple[float, ...]  # the widths the levels were cut at
    levels: tuple[NDArray[np.int32], ...]  # one ``door_regions`` array a width
    openings: NDArray[np.int32] | None = None  # ``opening_parts``; None: rule 5 at doorways only
    furniture: FurniturePieces | None = None  # rule 6; None: off

    @property
    def doorways(self) -> NDArray[np.int32]:
        """The regions at the doorway width (the first)."""
        return self.levels[0]


def passage_regions(grid: OccupancyGrid, params: RoomMapParams) -> PassageRegions | None:
    """Rule 3's regions at the doorway width, then at each wider passage; None when off.

    When rule 5 applies at openings, its parts (``opening_parts``) come with them, and
    the furniture pieces when rule 6 is on.
    """
    widths = params.passage_widths_m
    if not widths:
        return None
    pieces = FurniturePieces.of(grid, params.furniture_max_m)
    floor = _Floor.of(grid, pieces.pieces > 0)
    levels = tuple(_door_regions(floor, width) for width in widths)
    openings = None
    if params.splits_at_openings:
        openings = _opening_parts(floor, levels[0], params.room_opening_m)
    return PassageRegions(widths, levels, openings, pieces if params.furniture_rooms else None)


def opening_parts(
    grid: OccupancyGrid, doorways: NDArray[np.int32], width_m: float, furniture_max_m: float = 0.0
) -> NDArray[np.int32]:
    """Rule 5's parts at openings narrower than ``width_m``, within each doorway region.

    A space wider than the opening is a core (cells over half the width from walls) with
    the cells within √2 half-widths of it, by walking; what no core reaches (a corridor
    narrower than the opening) is one more part of its doorway region. So the rooms open on
    a wide corridor part from it, and a narrow corridor is never shared out among the
    rooms along it. Returns int32 parts, 0 where ``doorways`` is 0.
    """
    return _opening_parts(_Floor.of(grid, furniture(grid, furniture_max_m)), doorways, width_m)


def _opening_parts(floor: _Floor, doorways: NDArray[np.int32], width_m: float) -> NDArray[np.int32]:
    cores, core_cells = floor.cores(width_m)
    # a rectangular room's corners lie √2 half-widths from its core (+ a cell's rounding)
    reach_m = SQRT2 * width_m / 2 + floor.grid.resolution_m
    core_of = floor.nearest_core(cores, core_cells, reach_m)
    # a core claims cells of its own doorway region only, never across a doorway
    region_of_core = np.zeros(int(cores.max(initial=0)) + 1, dtype=np.int64)
    free_core = core_cells[doorways.ravel()[core_cells] > 0]  # furniture cells are in none
    region_of_core[cores.ravel()[free_core]] = doorways.ravel()[free_core]
    core_of[region_of_core[core_of] != doorways] = 0
    key = doorways.astype(np.int64) * (region_of_core.size + 1) + core_of
    inside = doorways > 0
    out = np.zeros(doorways.shape, dtype=np.int32)
    out[inside] = np.unique(key[inside], return_inverse=True)[1].ravel() + 1
    return out


def room_map(
    field: SampleField,
    labels: NDArray[np.int64],
    regions: PassageRegions | NDArray[np.int32] | None = None,
    params: RoomMapParams | None = None,
) -> NDArray[np.int32]:
    """Label the free cells the trajectory reaches with its areas (rules 1-3 and 5).

    Args:
        field: from ``nearest_samples``.
        labels: each sample's area (>= 1).
        regions: ``passage_regions`` (made with ``params``' widths), one ``door_regions``
            array (doorways alone), or None for rule 1 alone.
        params: the shares of rule 3 and whether rule 5 applies; default ``RoomMapParams()``.

    An area cut by rule 5 keeps its number on its largest part; the others get new numbers
    above every area's.
    """
    params = params or RoomMapParams()
    cells = label_cells(field, labels)
    if regions is None:
        return cells
    if isinstance(regions, np.ndarray):
        regions = PassageRegions(params.passage_widths_m[:1], (regions,))
    elif regions.widths_m != params.passage_widths_m:
        msg = f"regions cut at {regions.widths_m} m, parameters at {params.passage_widths_m} m"
        raise ValueError(msg)
    doorways = regions.doorways
    visited = np.zeros(int(doorways.max()) + 1, dtype=bool)
    visited[doorways.ravel()[field.source_cells]] = True
    visited[0] = True  # cells outside every region keep rule 1's label
    cells[~visited[doorways]] = 0
    undecided = cells > 0
    for index, level in enumerate(regions.levels):
        if not undecided.any():
            break
        share = params.region_share if index == 0 else params.opening_share
        cells, undecided = _give_dominated(cells, level, undecided, share)
    if params.region_plurality and undecided.any():
        cells, undecided = _give_dominated(cells, doorways, undecided, 0.0)
    if params.split_at_doorways:
        cells = split_at_doorways(cells, doorways)
        if params.splits_at_openings and regions.openings is not None:
            min_cells = round(params.min_room_m2 / field.resolution_m**2)
            cells = split_at_openings(cells, regions.openings, min_cells)
    if regions.furniture is not None:
        cells = regions.furniture.label(cells)
    return cells


def _give_dominated(
    cells: NDArray[np.int32], regions: NDArray[np.int32], undecided: NDArray[np.bool_], share: float
) -> tuple[NDArray[np.int32], NDArray[np.bool_]]:
    """Give each region's undecided cells to an area holding ``share`` of them (rule 3).

    Ties go to the lower label; at ``share`` 0 every region goes to its largest area.
    """
    both = undecided & (regions > 0)
    if not both.any():
        return cells, undecided
    unique, counts, _ = unique_pairs(regions[both], cells[both])
    totals = np.bincount(unique[:, 0], weights=counts)
    order = np.lexsort((unique[:, 1], -counts, unique[:, 0]))
    first = np.unique(unique[order, 0], return_index=True)[1]
    best = unique[order][first]
    dominant = counts[order][first] >= share * totals[best[:, 0]]
    owner = np.zeros(int(regions.max()) + 1, dtype=np.int32)
    owner[best[dominant, 0]] = best[dominant, 1]
    snapped = owner[regions]
    take = both & (snapped > 0)
    out = cells.copy()
    out[take] = snapped[take]
    return out, undecided & ~take


def split_at_doorways(labels: NDArray[np.int32], doorways: NDArray[np.int32]) -> NDArray[np.int32]:
    """Rule 5: an area's cells in several doorway regions become one room per region.

    The largest part keeps the area's number (ties: the lower region); the others are
    numbered from the largest label + 1, in order of (region, area).
    """
    named = labels > 0
    if not named.any():
        return labels
    top = int(labels.max()) + 1
    keys = doorways[named].astype(np.int64) * top + labels[named]
    pieces, inverse, sizes = np.unique(keys, return_inverse=True, return_counts=True)
    area = pieces % top
    order = np.lexsort((pieces // top, -sizes, area))
    largest = np.zeros(pieces.size, dtype=bool)
    largest[order[np.r_[True, area[order][1:] != area[order][:-1]]]] = True
    number = np.where(largest, area, 0)
    others = np.flatnonzero(~largest)
    number[others] = top + np.arange(others.size)
    out = labels.copy()
    out[named] = number[inverse.ravel()]
    return out


def split_at_openings(
    labels: NDArray[np.int32], regions: NDArray[np.int32], min_cells: int
) -> NDArray[np.int32]:
    """Rule 5 at openings: ``split_at_doorways`` at ``regions``, parts under ``min_cells`` kept.

    A part smaller than ``min_cells`` (a nook, the end of a corridor past a pillar) keeps
    its area's label; the others are numbered as ``split_at_doorways`` numbers them.
    """
    split = split_at_doorways(labels, regions)
    moved = split != labels
    if not moved.any():
        return split
    pieces, sizes = np.unique(split[moved], return_counts=True)
    back = moved & np.isin(split, pieces[sizes < min_cells])
    return np.where(back, labels, split)


def merge_overlapping(
    maps: list[NDArray[np.int32]], min_share: float = 0.5, top_labels: list[int] | None = None
) -> list[NDArray[np.int32]]:
    """Name the areas of several room maps (a fleet's robots) with one set of labels.

    Two labels of different maps are one room when their overlap is at least ``min_share``
    of the smaller's cells; merged transitively. Returns per map a lookup array: its label
    ``a`` is fleet label ``lookup[a]`` (1..k over all maps; ``lookup[0]`` = 0), for every
    ``a`` up to the map's largest label or its ``top_labels`` entry (a label with no cell).
    """
    tops = top_labels or [0] * len(maps)
    offsets = np.cumsum([0, *[max(int(m.max()), top) for m, top in zip(maps, tops, strict=True)]])
    parent = list(range(int(offsets[-1]) + 1))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a in range(len(maps)):
        for b in range(a + 1, len(maps)):
            both = (maps[a] > 0) & (maps[b] > 0)
            if not both.any():
                continue
            size_a = np.bincount(maps[a].ravel(), minlength=int(offsets[a + 1] - offsets[a]) + 1)
            size_b = np.bincount(maps[b].ravel(), minlength=int(offsets[b + 1] - offsets[b]) + 1)
            unique, counts, _ = unique_pairs(maps[a][both], maps[b][both])
            for (la, lb), count in zip(unique, counts, strict=True):
                if count >= min_share * min(size_a[la], size_b[lb]):
                    parent[root(int(offsets[a] + la))] = root(int(offsets[b] + lb))
    roots = sorted({root(i) for i in range(1, len(parent))})
    number = {r: n for n, r in enumerate(roots, start=1)}
    lookups = []
    for index in range(len(maps)):
        lookup = np.zeros(int(offsets[index + 1] - offsets[index]) + 1, dtype=np.int32)
        for label in range(1, lookup.size):
            lookup[label] = number[root(int(offsets[index] + label))]
        lookups.append(lookup)
    return lookups


def fleet_room_map(
    grid: OccupancyGrid,
    robots: list[tuple[NDArray[np.float64], NDArray[np.int64]]],
    params: RoomMapParams | None = None,
    regions: PassageRegions | NDArray[np.int32] | None = None,
) -> NDArray[np.int32]:
    """One room map from several robots' labelled trajectories (``(xy, areas)`` each).

    One robot: ``room_map``. Several: ``merged_room_map`` (rule 4).
    """
    params = params or RoomMapParams()
    fields = [nearest_samples(grid, xy, params) for xy, _ in robots]
    labels = [areas for _, areas in robots]
    if len(robots) == 1:
        return room_map(fields[0], labels[0], regions, params)
    everyone = nearest_samples(grid, np.concatenate([xy for xy, _ in robots]), params)
    return merged_room_map(fields, everyone, labels, regions, params)


def merged_room_map(
    fields: list[SampleField],
    everyone: SampleField,
    labels: list[NDArray[np.int64]],
    regions: PassageRegions | NDArray[np.int32] | None = None,
    params: RoomMapParams | None = None,
) -> NDArray[np.int32]:
    """Several robots' room map, their areas merged where they name the same place (rule 4).

    Args:
        fields: each robot's field (``nearest_samples`` of its poses).
        everyone: the field of all poses, robots concatenated in the order of ``fields``.
        labels: each robot's areas of its poses (>= 1).
        regions: ``passage_regions`` for rules 3 and 5, or None.
        params: rule 3's shares, rule 5 and ``merge_m``.
    """
    params = params or RoomMapParams()
    own = []
    for field, areas in zip(fields, labels, strict=True):
        near = room_map(field, areas, regions, params)
        near[field.distance_m > params.merge_m] = 0
        own.append(near)
    lookups = merge_overlapping(own, top_labels=[int(a.max(initial=0)) for a in labels])
    merged = np.concatenate([lookup[a] for lookup, a in zip(lookups, labels, strict=True)])
    return room_map(everyone, merged, regions, params)

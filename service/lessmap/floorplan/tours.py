"""Robot tours of a floor plan: every room visited, walked at a steady pace.

A robot starts in a random room and then walks, again and again, to one of the few
nearest rooms it has not visited yet (by path length, drawn at random, nearer ones more
likely). In each room it walks to the room's most central point (the maximum of the
room's distance transform) and to up to two more random points of the room with room to
stand, so it really walks in rather than touching the door. Paths come from the planner;
positions advance ``speed_m_per_frame`` along them each frame, and the heading turns
toward a point a little ahead at a bounded rate (turning on the spot when the path turns
back on itself).

Invariants:
    1. Every pose lies on a planner path: walkable, collision-free for the robot.
    2. Consecutive poses are at most ``speed_m_per_frame`` apart (0 while turning on the spot).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from lessmap.floorplan.planner import COMFORT_M

if TYPE_CHECKING:
    from lessmap.floorplan.grid import OccupancyGrid
    from lessmap.floorplan.options import TourOptions
    from lessmap.floorplan.planner import Planner

__all__ = ["RoomTargets", "Tour", "block_regions", "room_targets", "tour"]

TURN_ON_SPOT_DEG = 60.0  # a larger heading error stops the robot until it has turned


@dataclass(frozen=True, slots=True, kw_only=True)
class RoomTargets:
    """Where tours go: per room its walkable cells and its most central one."""

    regions: NDArray[np.int32]  # (rows, cols) planning cells: room of each, 0 off the graph
    centres: dict[int, tuple[int, int]]  # room -> (row, col)
    skipped: tuple[int, ...]  # rooms with no walkable cell


@dataclass(slots=True)
class Tour:
    """One robot's walk: a pose per frame, and the rooms whose centre it reached."""

    poses: NDArray[np.float64]  # (frames, 3): x, y metres; heading radians
    reached: dict[int, int] = field(default_factory=dict)  # room -> first frame at its centre
    path_m: float = 0.0


def room_targets(
    labels: NDArray[np.int32], walkable: NDArray[np.bool_], rooms: int | None = None
) -> RoomTargets:
    """The centre of every room of ``labels`` (1..``rooms``) that has a walkable cell."""
    regions = np.where(walkable, labels, 0).astype(np.int32)
    centres: dict[int, tuple[int, int]] = {}
    skipped: list[int] = []
    rooms = int(labels.max(initial=0)) if rooms is None else rooms
    # None for a label with no cell (the stubs leave that out).
    slices: list[Any] = list(ndimage.find_objects(regions, max_label=rooms))
    for room in range(1, rooms + 1):
        where = slices[room - 1]
        if where is None:
            skipped.append(room)
            continue
        inside = regions[where] == room
        depth = ndimage.distance_transform_edt(np.pad(inside, 1))[1:-1, 1:-1]
        r, c = np.unravel_index(int(np.argmax(depth)), inside.shape)
        centres[room] = (int(r) + where[0].start, int(c) + where[1].start)
    return RoomTargets(regions=regions, centres=centres, skipped=tuple(skipped))


def block_regions(
    walkable: NDArray[np.bool_], block_cells: int, min_cells: int
) -> NDArray[np.int32]:
    """Waypoint regions for a map without rooms: walkable parts of square blocks, 1..k.

    Parts of a block smaller than ``min_cells`` are left out (0).
    """
    rows, cols = walkable.shape
    labels = np.zeros(walkable.shape, dtype=np.int32)
    count = 0
    for r0 in range(0, rows, block_cells):
        for c0 in range(0, cols, block_cells):
            window = (slice(r0, r0 + block_cells), slice(c0, c0 + block_cells))
            parts, found = ndimage.label(walkable[window])
            sizes = np.bincount(parts.ravel(), minlength=found + 1)
            big = np.flatnonzero(sizes >= min_cells)
            big = big[big > 0]
            renumber = np.zeros(found + 1, dtype=np.int32)
            renumber[big] = np.arange(count + 1, count + 1 + len(big), dtype=np.int32)
            labels[window] = renumber[parts]
            count += len(big)
    return labels


def tour(
    planner: Planner,
    grid: OccupancyGrid,
    targets: RoomTargets,
    rng: np.random.Generator,
    options: TourOptions,
) -> Tour:
    """Walk one robot through every room of ``targets`` (module docstring)."""
    rooms = sorted(targets.centres)
    if not rooms:
        return Tour(poses=np.zeros((0, 3)))
    room = rooms[int(rng.integers(len(rooms)))]
    unvisited = set(rooms) - {room}
    here = planner.node(*targets.centres[room])
    corners: list[NDArray[np.float64]] = [planner.cells(np.array([here])).astype(np.float64)]
    arrivals: list[tuple[int, int]] = [(room, 0)]  # (room, corner index of its centre)
    here = _walk_room(planner, targets, room, here, rng, options, corners)
    while unvisited:
        room, path = _next_room(planner, targets, here, unvisited, rng, options)
        unvisited.discard(room)
        if path is None:
            continue
        corners.append(planner.pulled(path)[1:])
        arrivals.append((room, sum(len(c) for c in corners) - 1))
        here = _walk_room(planner, targets, room, int(path[-1]), rng, options, corners)
    cells = planner.map_cells(np.concatenate(corners))
    polyline = grid.cell_to_xy(cells[:, 0], cells[:, 1])
    return _follow(polyline, arrivals, options)


def _walk_room(
    planner: Planner,
    targets: RoomTargets,
    room: int,
    here: int,
    rng: np.random.Generator,
    options: TourOptions,
    corners: list[NDArray[np.float64]],
) -> int:
    """Walk to extra points of ``room`` from its centre; return the node reached."""
    low, high = options.points_per_room
    extra = int(rng.integers(low, high + 1)) - 1
    if extra <= 0:
        return here
    r, c = np.nonzero(targets.regions == room)
    clearance = planner.clearance_m[r, c]
    roomy = clearance >= min(planner.robot_radius_m + COMFORT_M, float(clearance.max()))
    r, c = r[roomy], c[roomy]
    for _ in range(extra):
        pick = int(rng.integers(len(r)))
        goal = planner.node(int(r[pick]), int(c[pick]))
        ends = planner.cells(np.array([here, goal]))
        straight_m = planner.resolution_m * float(np.hypot(*(ends[1] - ends[0])))
        dist, pred = planner.costs_from(here, limit=4.0 * straight_m + 2.0)
        if not np.isfinite(dist[goal]):
            dist, pred = planner.costs_from(here)
        if not np.isfinite(dist[goal]):
            continue
        corners.append(planner.pulled(planner.path(pred, here, goal))[1:])
        here = goal
    return here


def _next_room(
    planner: Planner,
    targets: RoomTargets,
    here: int,
    unvisited: set[int],
    rng: np.random.Generator,
    options: TourOptions,
) -> tuple[int, NDArray[np.int64] | None]:
    """Draw the next room among the nearest unvisited; its path (None: unreachable)."""
    goals = {room: planner.node(*targets.centres[room]) for room in sorted(unvisited)}
    wanted = min(options.nearest_rooms, len(goals))
    limit = 16.0
    while True:
        dist, pred = planner.costs_from(here, limit=limit)
        reached = sorted(
            (float(dist[node]), room) for room, node in goals.items() if np.isfinite(dist[node])
        )
        if len(reached) >= wanted or not np.isfinite(limit):
            break
        limit = limit * 2.0 if limit < 1000.0 else np.inf
    if not reached:
        return min(goals), None
    nearest = reached[:wanted]
    weights = 1.0 / np.arange(1, len(nearest) + 1)
    pick = int(rng.choice(len(nearest), p=weights / weights.sum()))
    room = nearest[pick][1]
    return room, planner.path(pred, here, goals[room])


def _follow(
    polyline: NDArray[np.float64], arrivals: list[tuple[int, int]], options: TourOptions
) -> Tour:
    """Poses every frame along the polyline (module docstring); rooms by first frame there."""
    keep = np.concatenate([[True], np.hypot(*np.diff(polyline, axis=0).T) > 1e-9])
    index_of = np.cumsum(keep) - 1  # old corner index -> kept corner index
    points = polyline[keep]
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    arrival_arc = sorted((float(arc[index_of[i]]), room) for room, i in arrivals)
    total = float(arc[-1])
    arcs = arc.tolist()
    xs, ys = points[:, 0].tolist(), points[:, 1].tolist()

    def at(s: float) -> tuple[float, float]:
        if len(arcs) == 1:
            return xs[0], ys[0]
        i = min(max(bisect.bisect_right(arcs, s) - 1, 0), len(arcs) - 2)
        share = (s - arcs[i]) / (arcs[i + 1] - arcs[i])
        share = min(max(share, 0.0), 1.0)
        return xs[i] + share * (xs[i + 1] - xs[i]), ys[i] + share * (ys[i + 1] - ys[i])

    speed = options.speed_m_per_frame
    turn = math.radians(options.turn_rate_deg_s) / options.rate_hz
    spot = math.radians(TURN_ON_SPOT_DEG)
    x, y = at(0.0)
    ax, ay = at(min(options.lookahead_m, total))
    theta = math.atan2(ay - y, ax - x) if total > 0 else 0.0
    s = 0.0
    poses: list[tuple[float, float, float]] = []
    reached: dict[int, int] = {}
    pending = 0
    limit = options.max_frames if options.max_frames is not None else math.inf
    while len(poses) < limit:
        x, y = at(s)
        while pending < len(arrival_arc) and arrival_arc[pending][0] <= s + 1e-9:
            reached.setdefault(arrival_arc[pending][1], len(poses))
            pending += 1
        poses.append((x, y, theta))
        if s >= total:
            break
        ax, ay = at(min(s + options.lookahead_m, total))
        error = (math.atan2(ay - y, ax - x) - theta + math.pi) % (2.0 * math.pi) - math.pi
        theta = (theta + max(-turn, min(turn, error)) + math.pi) % (2.0 * math.pi) - math.pi
        if abs(error) <= spot:
            s = min(s + speed, total)
    walked = min(s, total)
    return Tour(
        poses=np.asarray(poses, dtype=np.float64).reshape(-1, 3), reached=reached, path_m=walked
    )

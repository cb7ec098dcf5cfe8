"""Robots touring a real floor plan with a simulated sensor: frames plus their ground truth.

The pieces: ``planner`` (walkable cells, collision-free paths), ``tours`` (every room,
steady pace), ``landmarks`` (wall faces thinned per sensor, corners), ``sensors`` (line of
sight, detection, false associations) and ``truth`` (room of every frame, room changes).
Without ground-truth rooms the tours visit the walkable parts of ``block_m`` squares
instead, and every frame's room is 0 (unknown).

Invariants:
    1. Randomness comes from ``numpy.random.default_rng([seed, stream, robot])`` only: the
       same call gives the same run, and adding robots leaves the others unchanged.
    2. Robot ``i`` is ``robot<i>``; its frame ``seq`` has stamp ``seq / rate_hz``; frames
       are ordered by stamp, then robot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.floorplan.grid import FloorplanError
from lessmap.floorplan.landmarks import Sites, corner_faces, thin_faces, wall_faces
from lessmap.floorplan.planner import build_planner, walkable_cells
from lessmap.floorplan.sensors import detect, visible_sites
from lessmap.floorplan.tours import block_regions, room_targets, tour
from lessmap.floorplan.truth import RoomChange, nearest_rooms, room_changes, rooms_along
from lessmap.progress import NO_PROGRESS, tracked
from lessmap.sim.simulator import TruthRow

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from numpy.typing import NDArray

    from lessmap.floorplan.grid import OccupancyGrid
    from lessmap.floorplan.options import FloorplanOptions, SensorProfile
    from lessmap.progress import Progress

__all__ = ["FloorplanRun", "simulate_floorplan"]

_ROUTE, _SENSOR = 0, 1  # random streams, per robot

_BLOCK_FRAMES = 2000  # poses whose sight lines are computed together


@dataclass(slots=True, kw_only=True)
class FloorplanRun:
    """A run: frames-file rows, truth rows (same order), room changes, and what was toured."""

    options: FloorplanOptions
    frames: list[dict[str, Any]]
    truth: list[TruthRow]
    room_changes: list[RoomChange]
    landmarks: int  # landmark ids the sensor could report
    rooms: int  # rooms of the ground truth (0 without)
    rooms_visited: tuple[int, ...]  # rooms (or waypoint squares) whose centre a robot reached
    rooms_skipped: tuple[int, ...]  # rooms no free path reaches
    path_m: dict[str, float]  # walked per robot


def simulate_floorplan(
    grid: OccupancyGrid,
    labels: NDArray[np.int32] | None,
    options: FloorplanOptions,
    progress: Callable[[str], None] | None = None,
    steps: Progress = NO_PROGRESS,
) -> FloorplanRun:
    """Tour ``grid`` with ``options.robots`` robots; ``labels`` are the true rooms (1..k).

    ``progress`` hears what was planned (a line a robot), ``steps`` counts the frames sensed.

    Raises:
        FloorplanError: bad options, labels of another shape than the map, or no room
            (or free square) that a robot can reach.
    """
    _check(options)
    say = progress or (lambda _text: None)
    if labels is not None and labels.shape != grid.shape:
        msg = (
            f"labels are {labels.shape[1]}x{labels.shape[0]} pixels, "
            f"the map {grid.shape[1]}x{grid.shape[0]}"
        )
        raise FloorplanError(msg)
    walkable = walkable_cells(grid.free)
    planner = build_planner(grid, walkable, options.robot_radius_m)
    if labels is None:
        block = max(1, round(options.block_m / grid.resolution_m))
        regions = block_regions(walkable, block, max(1, round(1.0 / grid.resolution_m**2)))
        targets = room_targets(planner.coarse(regions), planner.walkable, int(regions.max()))
        truth_rooms = np.zeros(grid.shape, dtype=np.int32)
    else:
        targets = room_targets(planner.coarse(labels), planner.walkable, int(labels.max()))
        truth_rooms = nearest_rooms(labels)
    if not targets.centres:
        msg = "no room is reachable: no walkable cell lies in a ground-truth room"
        raise FloorplanError(msg)
    sites = _sites(grid, walkable, options.sensor)
    say(
        f"{grid.shape[1]}x{grid.shape[0]} cells of {grid.resolution_m} m, "
        f"{len(targets.centres)} {'rooms' if labels is not None else 'squares'} to visit "
        f"({len(targets.skipped)} unreachable), {sites.count} landmarks ({options.sensor.name}), "
        f"{options.robots} robot(s)"
    )
    rows: list[tuple[int, int, dict[str, Any], TruthRow]] = []
    changes: list[tuple[int, int, RoomChange]] = []
    visited: set[int] = set()
    path_m: dict[str, float] = {}
    for index in range(options.robots):
        robot = f"robot{index}"
        walk = tour(planner, grid, targets, _rng(options.seed, _ROUTE, index), options.tour)
        visited |= set(walk.reached)
        path_m[robot] = round(walk.path_m, 3)
        say(f"{robot}: {len(walk.poses)} frames, {walk.path_m:.0f} m")
        along = rooms_along(grid, truth_rooms, walk.poses)
        if labels is not None:
            changes += [(c.seq, index, c) for c in room_changes(robot, along, walk.poses)]
        sensed = _sensed(grid, sites, walk.poses, _rng(options.seed, _SENSOR, index), options)
        steps.stage(f"{robot}: sensing", len(walk.poses))
        for seq, features in enumerate(tracked(sensed, steps)):
            x, y, theta = (round(float(v), 4) for v in walk.poses[seq])
            stamp = round(seq / options.tour.rate_hz, 6)
            frame = {"robot": robot, "seq": seq, "stamp": stamp, "features": features}
            frame["pose"] = [x, y, theta]
            truth = TruthRow(robot, seq, stamp, int(along[seq]), x, y, None, float("inf"))
            rows.append((seq, index, frame, truth))
    rows.sort(key=lambda row: (row[0], row[1]))
    changes.sort(key=lambda change: (change[0], change[1]))
    return FloorplanRun(
        options=options,
        frames=[row[2] for row in rows],
        truth=[row[3] for row in rows],
        room_changes=[change[2] for change in changes],
        landmarks=sites.count,
        rooms=0 if labels is None else int(labels.max(initial=0)),
        rooms_visited=tuple(sorted(visited)),
        rooms_skipped=targets.skipped,
        path_m=path_m,
    )


def _sensed(
    grid: OccupancyGrid,
    sites: Sites,
    poses: NDArray[np.float64],
    rng: np.random.Generator,
    options: FloorplanOptions,
) -> Iterator[list[int]]:
    """Yield each pose's frame (sorted landmark ids), computing sight lines in blocks."""
    for start in range(0, len(poses), _BLOCK_FRAMES):
        block = poses[start : start + _BLOCK_FRAMES]
        for seen in visible_sites(grid, sites, block, options.sensor):
            yield detect(rng, sites, seen, options.sensor)


def _check(options: FloorplanOptions) -> None:
    tour_options = options.tour
    problems = [
        (options.robots >= 1, f"robots must be at least 1, got {options.robots}"),
        (options.seed >= 0, f"seed must be at least 0, got {options.seed}"),
        (tour_options.rate_hz > 0, f"rate must be above 0 Hz, got {tour_options.rate_hz}"),
        (
            tour_options.speed_m_per_frame > 0,
            f"speed must be above 0 m a frame, got {tour_options.speed_m_per_frame}",
        ),
        (
            tour_options.max_frames is None or tour_options.max_frames >= 1,
            f"max frames must be at least 1, got {tour_options.max_frames}",
        ),
        (
            options.robot_radius_m >= 0,
            f"robot radius must be at least 0 m, got {options.robot_radius_m}",
        ),
    ]
    for ok, msg in problems:
        if not ok:
            raise FloorplanError(msg)


def _rng(seed: int, stream: int, robot: int) -> np.random.Generator:
    return np.random.default_rng([seed, stream, robot])


def _sites(grid: OccupancyGrid, walkable: NDArray[np.bool_], sensor: SensorProfile) -> Sites:
    """The landmark sites of one sensor: thinned wall faces, corners first when it uses them."""
    faces = wall_faces(grid, walkable)
    chosen = thin_faces(faces, sensor.wall_spacing_m)
    if sensor.corners:
        corners = corner_faces(grid, walkable, faces)
        chosen = np.concatenate([corners, np.setdiff1d(chosen, corners)])
    return Sites(faces=faces.take(chosen), layers=sensor.layers)

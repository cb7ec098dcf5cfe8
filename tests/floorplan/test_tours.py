"""Tours: every reachable room, collision-free poses, a steady pace, smooth headings."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy import ndimage

from lessmap.floorplan.example import EXAMPLE_LABELS, EXAMPLE_MAP
from lessmap.floorplan.grid import OccupancyGrid, load_grid, room_labels
from lessmap.floorplan.options import TourOptions
from lessmap.floorplan.planner import Planner, build_planner, walkable_cells
from lessmap.floorplan.tours import (
    RoomTargets,
    Tour,
    block_regions,
    room_targets,
    tour,
)
from tests.floorplan.helpers import two_rooms

OPTIONS = TourOptions()


def targets_of(planner: Planner, labels: np.ndarray) -> RoomTargets:
    return room_targets(planner.coarse(labels), planner.walkable, int(labels.max()))


@functools.cache
def example() -> tuple[OccupancyGrid, Planner, RoomTargets]:
    grid = load_grid(EXAMPLE_MAP)
    planner = build_planner(grid, walkable_cells(grid.free), 0.2)
    return grid, planner, targets_of(planner, room_labels(EXAMPLE_LABELS))


@functools.cache
def example_tour(seed: int) -> Tour:
    grid, planner, targets = example()
    return tour(planner, grid, targets, np.random.default_rng(seed), OPTIONS)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_room_is_visited(seed: int) -> None:
    _, _, targets = example()
    walk = example_tour(seed)
    assert sorted(targets.centres) == [1, 2, 3, 4, 5, 6, 7]
    assert targets.skipped == ()
    assert sorted(walk.reached) == sorted(targets.centres)
    reached_at = sorted(walk.reached.values())
    assert reached_at[0] == 0  # the robot starts at its first room's centre
    assert reached_at == sorted(set(reached_at))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_pose_is_walkable_with_room_to_spare(seed: int) -> None:
    grid, _, _ = example()
    poses = example_tour(seed).poses
    cells = grid.xy_to_cell(poses[:, :2])
    assert walkable_cells(grid.free)[cells[:, 0], cells[:, 1]].all()
    # Every door of the example is wider than the robot: it never needs to brush a wall.
    clearance_m = ndimage.distance_transform_edt(grid.free) * grid.resolution_m
    assert clearance_m[cells[:, 0], cells[:, 1]].min() >= 0.2 - 0.05
    # Nor does the straight line between two frames cross an occupied cell.
    t = np.linspace(0.0, 1.0, 9)[:, None, None]
    between = poses[None, :-1, :2] + t * (poses[None, 1:, :2] - poses[None, :-1, :2])
    cells = grid.xy_to_cell(between.reshape(-1, 2))
    assert grid.free[cells[:, 0], cells[:, 1]].all()


@pytest.mark.parametrize("seed", [0, 1])
def test_robots_walk_at_the_given_pace_and_turn_smoothly(seed: int) -> None:
    walk = example_tour(seed)
    step = np.hypot(*np.diff(walk.poses[:, :2], axis=0).T)
    assert step.max() <= OPTIONS.speed_m_per_frame + 1e-9
    moving = step > 0
    assert np.mean(np.isclose(step[moving], OPTIONS.speed_m_per_frame, atol=1e-6)) > 0.95
    assert np.mean(moving) > 0.8  # turning on the spot is the exception
    assert sum(step) == pytest.approx(walk.path_m, rel=0.01)
    turn = np.abs((np.diff(walk.poses[:, 2]) + np.pi) % (2 * np.pi) - np.pi)
    assert turn.max() <= math.radians(OPTIONS.turn_rate_deg_s) / OPTIONS.rate_hz + 1e-9
    # The heading follows the path: within 60° of the direction of travel.
    direction = np.arctan2(*np.diff(walk.poses[:, 1::-1], axis=0).T)
    off = np.abs((direction - walk.poses[1:, 2] + np.pi) % (2 * np.pi) - np.pi)
    assert np.mean(off[moving] < math.radians(60.0)) > 0.95


def test_the_frame_limit_stops_the_robot() -> None:
    grid, planner, targets = example()
    limited = TourOptions(max_frames=50)
    walk = tour(planner, grid, targets, np.random.default_rng(0), limited)
    assert len(walk.poses) == 50
    assert np.array_equal(walk.poses, example_tour(0).poses[:50])
    assert len(walk.reached) < len(targets.centres)


def test_a_door_narrower_than_the_robot_is_still_used() -> None:
    grid, labels = two_rooms(door_m=0.3)
    planner = build_planner(grid, walkable_cells(grid.free), robot_radius_m=0.2)
    targets = targets_of(planner, labels)
    walk = tour(planner, grid, targets, np.random.default_rng(0), OPTIONS)
    assert sorted(walk.reached) == [1, 2]


def test_a_room_no_path_reaches_is_skipped() -> None:
    grid, labels = two_rooms(door_m=0.0)  # walkable: the larger room, here the first found
    targets = targets_of(build_planner(grid, walkable_cells(grid.free), 0.2), labels)
    assert sorted(targets.centres) == [1]
    assert targets.skipped == (2,)


def test_a_map_without_rooms_is_toured_by_squares() -> None:
    grid, _ = two_rooms(door_m=1.0)
    walkable = walkable_cells(grid.free)
    regions = block_regions(walkable, block_cells=40, min_cells=400)
    assert regions.max() >= 8  # 8 m x 3 m in 2 m squares
    assert not (regions[~walkable] > 0).any()
    planner = build_planner(grid, walkable, 0.2)
    walk = tour(planner, grid, targets_of(planner, regions), np.random.default_rng(0), OPTIONS)
    assert len(walk.reached) == regions.max()

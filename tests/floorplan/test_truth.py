"""Ground truth: the room of every frame, the room changes, no flicker at door lines."""

from __future__ import annotations

import functools
import itertools

import numpy as np

from lessmap.floorplan.example import DOORS_M, EXAMPLE_LABELS, EXAMPLE_MAP
from lessmap.floorplan.grid import load_grid, room_labels
from lessmap.floorplan.options import FloorplanOptions
from lessmap.floorplan.simulation import FloorplanRun, simulate_floorplan
from lessmap.floorplan.truth import nearest_rooms, room_changes, rooms_along
from tests.floorplan.helpers import RES, two_rooms

# Rooms of the example, numbered as room_labels numbers them: offices 1-3 (top row), the
# corridor 4, the meeting room 5, the open plan 6, the store room 7.
PAIRS = (  # the rooms each door of DOORS_M joins, in its order
    frozenset({1, 4}),
    frozenset({2, 4}),
    frozenset({3, 4}),
    frozenset({1, 2}),
    frozenset({4, 5}),
    frozenset({4, 6}),
    frozenset({6, 7}),
)
DOORS = dict(zip(PAIRS, DOORS_M, strict=True))


@functools.cache
def example_run(seed: int) -> FloorplanRun:
    grid = load_grid(EXAMPLE_MAP)
    return simulate_floorplan(grid, room_labels(EXAMPLE_LABELS), FloorplanOptions(seed=seed))


def test_door_lines_belong_to_a_room_beside_them() -> None:
    labels = room_labels(EXAMPLE_LABELS)
    rooms = nearest_rooms(labels)
    grid = load_grid(EXAMPLE_MAP)
    assert (rooms[grid.free] > 0).all()
    assert np.array_equal(rooms[labels > 0], labels[labels > 0])
    (row, col) = grid.xy_to_cell(np.array([[12.5, 5.675]]))[0]  # on the open-plan line
    assert labels[row, col] == 0
    assert rooms[row, col] in {4, 6}


def test_a_brief_visit_across_a_door_line_is_no_room_change() -> None:
    grid, labels = two_rooms()
    rooms = nearest_rooms(labels)
    door_x = 4.0 + 2 * RES  # the middle of the two-cell wall
    x = np.concatenate([np.linspace(3.0, door_x + 0.15, 20), np.linspace(door_x + 0.15, 3.0, 20)])
    poses = np.column_stack([x, np.full_like(x, 1.55), np.zeros_like(x)])
    along = rooms_along(grid, rooms, poses)
    assert set(along.tolist()) == {1}  # 0.3 m into room 2 and back: a brush, not a visit
    x = np.concatenate([np.linspace(3.0, 5.5, 30), np.linspace(5.5, 3.0, 30)])
    poses = np.column_stack([x, np.full_like(x, 1.55), np.zeros_like(x)])
    along = rooms_along(grid, rooms, poses)
    changes = room_changes("r", along, poses)
    assert [(c.from_room, c.to_room) for c in changes] == [(1, 2), (2, 1)]
    assert all(abs(c.x - door_x) < 0.1 for c in changes)


def test_room_changes_of_the_example_pass_its_doors() -> None:
    for seed in (0, 1):
        run = example_run(seed)
        assert len(run.room_changes) >= 12  # seven rooms, two robots
        for change in run.room_changes:
            pair = frozenset({change.from_room, change.to_room})
            assert pair in DOORS, change
            x0, y0, x1, y1 = DOORS[pair]  # the opening through the wall
            assert x0 - 0.1 <= change.x <= x1 + 0.1, change
            assert y0 - 0.1 <= change.y <= y1 + 0.1, change


def test_room_changes_are_the_steps_of_the_truth_rows() -> None:
    run = example_run(0)
    for robot in ("robot0", "robot1"):
        rows = [row for row in run.truth if row.robot == robot]
        assert [row.seq for row in rows] == list(range(len(rows)))
        steps = [(b.seq, a.room, b.room) for a, b in itertools.pairwise(rows) if a.room != b.room]
        mine = [(c.seq, c.from_room, c.to_room) for c in run.room_changes if c.robot == robot]
        assert steps == mine
        assert min(row.room for row in rows) >= 1

"""The simulated building, its ground truth, and LESS-mapping scored against it (no mocks).

Run with ``-s`` to see the measured figures of the acceptance checks.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import random
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.core import Partitioner, PartitionParams, Transition
from lessmap.files.frames import read_frames
from lessmap.sim.building import FACE_OFFSET_M, Building, Door, generate_building
from lessmap.sim.groundtruth import Score, changes_from_truth, score
from lessmap.sim.simulator import (
    SimRun,
    iter_frames,
    read_truth,
    run_paths,
    simulate,
    write_run,
)

if TYPE_CHECKING:
    from pathlib import Path

TOLERANCE_FRAMES = 8  # 4 s at 2 Hz: the CovRate needs a few frames in the new room
SCANNER = {"fov_deg": 270.0}  # a SICK LMS1xx / Hokuyo UTM-30LX class 2-D laser scanner


def _report(text: str) -> None:
    print(f"\n{text}")  # noqa: T201 -- the measured figures, shown by pytest -s


@functools.cache
def _run(seed: int, rooms: int, fov_deg: float = 360.0) -> SimRun:
    return simulate(seed, rooms=rooms, fov_deg=fov_deg)


@functools.cache
def _segment(seed: int, rooms: int, fov_deg: float) -> dict[str, list[Transition]]:
    """Offline LESS-mapping of a run: one laser-profile partitioner per robot."""
    partitioners: dict[str, Partitioner] = {}
    found: dict[str, list[Transition]] = {}
    for frame in _run(seed, rooms, fov_deg).frames:
        robot = frame["robot"]
        partitioner = partitioners.setdefault(
            robot, Partitioner(PartitionParams.from_profile("laser"))
        )
        transition = partitioner.observe(frame["seq"], frame["stamp"], frame["features"])
        if transition is not None:
            found.setdefault(robot, []).append(transition)
    return found


def _pooled(cases: list[tuple[int, int]], fov_deg: float) -> Score:
    """Score several runs as one (robots renamed per run so their changes stay apart)."""
    changes: list[dict[str, Any]] = []
    detections: dict[str, list[Transition]] = {}
    positions: dict[tuple[str, int], tuple[float, float]] = {}
    doors: list[tuple[float, float]] = []
    for index, (seed, rooms) in enumerate(cases):
        run = _run(seed, rooms, fov_deg)
        tag = f"{seed}/{rooms}/"
        offset = 1000.0 * index  # a door counts for its own building only: set them apart
        changes += [{"robot": tag + c.robot, "seq": c.seq} for c in run.room_changes]
        detections |= {tag + r: t for r, t in _segment(seed, rooms, fov_deg).items()}
        positions |= {(tag + t.robot, t.seq): (t.x + offset, t.y) for t in run.truth}
        doors += [(d.x + offset, d.y) for d in run.building.doors]
    return score(
        changes, detections, positions=positions, doors=doors, tolerance_frames=TOLERANCE_FRAMES
    )


# -- the world ---------------------------------------------------------------------------------


def test_same_seed_gives_the_same_run() -> None:
    first, again = (
        simulate(3, rooms=6, frames_per_robot=120),
        simulate(3, rooms=6, frames_per_robot=120),
    )
    assert first.frames == again.frames
    assert first.truth == again.truth
    assert first.building == again.building
    assert simulate(4, rooms=6, frames_per_robot=120).frames != first.frames


def test_robots_are_independent_of_fleet_size() -> None:
    alone = simulate(5, robots=1, frames_per_robot=80)
    fleet = simulate(5, robots=3, frames_per_robot=80)
    assert [f for f in fleet.frames if f["robot"] == "robot0"] == alone.frames


@pytest.mark.parametrize("layout", ["grid", "corridor"])
@pytest.mark.parametrize("rooms", [1, 5, 8])
def test_building_is_consistent(layout: str, rooms: int) -> None:
    building = generate_building(random.Random(rooms), rooms, layout=layout)
    assert len(building.rooms) == rooms + (layout == "corridor")
    assert len({m.id for m in building.landmarks}) == len(building.landmarks)
    for door in building.doors:
        a, b = door.rooms
        assert building.room_at(*door.side_point(a, 0.3)) == a
        assert building.room_at(*door.side_point(b, 0.3)) == b
    reachable, todo = {0}, [0]
    while todo:
        for _, other in building.neighbours(todo.pop()):
            if other not in reachable:
                reachable.add(other)
                todo.append(other)
    assert reachable == {room.index for room in building.rooms}
    for mark in building.landmarks:
        assert building.room_at(mark.x + 0.1 * mark.nx, mark.y + 0.1 * mark.ny) == mark.room


def test_walls_block_and_doors_let_through() -> None:
    building = _run(0, 6).building
    door = building.doors[0]
    a, b = door.rooms
    ax, ay = door.side_point(a, 1.0)
    bx, by = door.side_point(b, 1.0)
    assert building.line_of_sight(ax, ay, bx, by)  # straight through the opening
    shift = door.width_m  # the same line moved along the wall hits it
    moved = (ax, ay + shift, bx, by + shift) if door.vertical else (ax + shift, ay, bx + shift, by)
    assert not building.line_of_sight(*moved)
    # seen from a room's centre, another room's landmark is seen through a door opening
    hidden = 0
    for room in building.rooms:
        x, y = room.rect.centre
        seen = set(building.visible(x, y, 0.0, range_m=100.0))
        for mark in building.landmarks:
            if mark.room == room.index:
                continue
            tx, ty = mark.x + FACE_OFFSET_M * mark.nx, mark.y + FACE_OFFSET_M * mark.ny
            through = any(_crosses_opening(x, y, tx, ty, d) for d in building.doors)
            if mark.id in seen:
                assert through
            hidden += mark.id not in seen
    assert hidden > len(building.landmarks) / 2


def _crosses_opening(px: float, py: float, qx: float, qy: float, door: Door) -> bool:
    """Whether P→Q passes through the door's opening (a brute-force, independent check)."""
    if door.vertical:
        if (px - door.x) * (qx - door.x) > 0 or px == qx:
            return False
        y = py + (door.x - px) / (qx - px) * (qy - py)
        return abs(y - door.y) < door.width_m / 2
    if (py - door.y) * (qy - door.y) > 0 or py == qy:
        return False
    x = px + (door.y - py) / (qy - py) * (qx - px)
    return abs(x - door.x) < door.width_m / 2


@pytest.mark.parametrize("layout", ["grid", "corridor"])
def test_robot_away_from_doors_sees_mostly_its_room(layout: str) -> None:
    own = total = 0
    for seed in range(3):
        run = simulate(seed, rooms=6, frames_per_robot=200, layout=layout)
        building, opts = run.building, run.options
        for frame, row in zip(run.frames, run.truth, strict=True):
            if row.door_distance_m >= 1.5:
                theta = frame["pose"][2]  # the heading is in the frame, the rest in the truth
                seen = building.visible(row.x, row.y, theta, opts.range_m, opts.fov_deg)
                own += sum(building.landmarks[i].room == row.room for i in seen)
                total += len(seen)
    _report(f"{layout}: {own / total:.1%} of what is seen >= 1.5 m from a door is in the room")
    assert own / total >= 0.9


def test_frames_have_the_dataset_format(tmp_path: Path) -> None:
    run = simulate(1, rooms=6, robots=3, frames_per_robot=60)
    stamps = [f["stamp"] for f in run.frames]
    assert stamps == sorted(stamps)
    for frame, truth in zip(run.frames, run.truth, strict=True):
        assert set(frame) == {"robot", "seq", "stamp", "features", "pose"}
        assert (frame["robot"], frame["seq"]) == (truth.robot, truth.seq)
        assert frame["features"] == sorted(set(frame["features"]))
    for robot in ("robot0", "robot1", "robot2"):
        assert [f["seq"] for f in run.frames if f["robot"] == robot] == list(range(60))
    paths = write_run(run, tmp_path, "sim")
    rows = list(read_frames(paths.frames))  # the service's own reader accepts the file
    assert [(r.robot, r.seq, list(r.features)) for r in rows] == [
        (f["robot"], f["seq"], f["features"]) for f in run.frames
    ]
    lines = [json.loads(line) for line in paths.truth.read_text().splitlines()]
    assert lines[0]["door_near"]["door"] == run.truth[0].door
    changes = changes_from_truth(lines)
    assert [(c["robot"], c["seq"]) for c in changes] == [(c.robot, c.seq) for c in run.room_changes]
    document = json.loads(paths.building.read_text())
    assert Building.from_json(document) == run.building
    assert len(document["room_changes"]) == len(run.room_changes)
    back = read_truth(paths.frames)  # the one reader of these files gives the run back
    assert back.rows == tuple(run.truth)
    assert back.changes == tuple(run.room_changes)
    assert back.doors == run.building.doors
    assert back.landmarks == {m.id: (m.x, m.y) for m in run.building.landmarks}
    assert len(back.walls) == len(run.building.walls)
    frame = next(f for f in run.frames if (f["robot"], f["seq"]) == ("robot1", 5))
    assert back.positions()[("robot1", 5)] == tuple(frame["pose"][:2])


def test_truth_files_that_do_not_fit_are_named(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"must end in \.frames\.jsonl"):
        run_paths(tmp_path / "sim.jsonl")
    assert run_paths(tmp_path / "a.b.frames.jsonl").truth == tmp_path / "a.b.truth.jsonl"
    paths = write_run(simulate(2, rooms=3, robots=1, frames_per_robot=80), tmp_path, "sim")
    lines = paths.truth.read_text().splitlines()
    document = json.loads(paths.building.read_text())
    del document["room_changes"]
    paths.building.write_text(json.dumps(document))
    assert read_truth(paths.frames).changes  # derived from the rows
    rooms = [json.loads(line)["room"] for line in lines]
    first = next(k for k, (a, b) in enumerate(itertools.pairwise(rooms), start=1) if a != b)
    bad = json.loads(lines[first])
    bad["door_near"] = None  # the first frame in the new room names no door
    lines[first] = json.dumps(bad)
    paths.truth.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="without a door"):
        read_truth(paths.frames)
    paths.truth.write_text(lines[0] + "\n" + '{"robot": "robot0", "seq": 1}' + "\n")
    with pytest.raises(ValueError, match=r"sim\.truth\.jsonl:2: not a truth row"):
        read_truth(paths.frames)
    paths.truth.unlink()
    with pytest.raises(FileNotFoundError):
        read_truth(paths.frames)


def test_every_room_change_happens_at_its_door() -> None:
    for seed in range(3):
        run = _run(seed, 6)
        where = {(t.robot, t.seq): t for t in run.truth}
        assert len(run.room_changes) >= 20  # routes go back and forth through the doors
        for change in run.room_changes:
            door = run.doors[change.door]
            at = where[(change.robot, change.seq)]
            assert set(door.rooms) == {change.from_room, change.to_room}
            assert math.hypot(at.x - door.x, at.y - door.y) <= 1.5


def test_iter_frames_paces_by_stamp() -> None:
    run = simulate(0, robots=2, frames_per_robot=4)
    now = [100.0]
    waits: list[float] = []

    def sleep(seconds: float) -> None:
        waits.append(seconds)
        now[0] += seconds

    frames = list(iter_frames(run, speed=2.0, sleep=sleep, clock=lambda: now[0]))
    assert frames == run.frames
    assert now[0] - 100.0 == pytest.approx((run.frames[-1]["stamp"] - run.frames[0]["stamp"]) / 2)
    assert list(iter_frames(run)) == run.frames


def test_unknown_option_is_named() -> None:
    with pytest.raises(TypeError, match="fov"):
        simulate(fov=90)


# -- scoring -----------------------------------------------------------------------------------


def test_score_counts_by_hand() -> None:
    changes = [{"robot": "a", "seq": 10}, {"robot": "a", "seq": 40}, {"robot": "b", "seq": 5}]
    detections = {
        "a": [{"seq": 14, "boundary_seq": 10}, {"seq": 25, "boundary_seq": 24}],
        "b": [{"seq": 30, "boundary_seq": 28}],
    }
    positions = {("a", 10): (0.0, 0.5), ("a", 24): (9.0, 9.0), ("b", 28): (3.0, 0.0)}
    result = score(changes, detections, positions=positions, doors=[(0.0, 0.0)], tolerance_frames=5)
    assert (result.changes, result.transitions) == (3, 3)
    assert result.recall == pytest.approx(1 / 3)  # only a@10 is followed within 5 frames
    assert result.recall_boundary == pytest.approx(1 / 3)
    assert result.recall_any == pytest.approx(2 / 3)  # a@10 at 14, b@5 at 30; a@40 never
    assert result.precision == pytest.approx(1 / 3)
    assert result.precision_door == pytest.approx(1 / 3)
    assert result.precision_door_at_seq is None  # no positions for the detection frames
    assert (result.latency_mean, result.latency_median, result.latency_max) == (14.5, 14.5, 25)
    assert "recall 33%" in result.describe()
    assert result.as_dict()["recall"] == 0.3333


# -- LESS-mapping on the simulated building: the acceptance check --------------------------------


def test_laser_scanner_transitions_follow_room_changes_at_doors() -> None:
    """≥ 80 % of room changes followed by a transition within 8 frames, < 20 % away from doors."""
    result = _pooled([(0, 6), (1, 6), (0, 8), (1, 8)], SCANNER["fov_deg"])
    _report(f"270° laser, laser profile: {result.describe()}")
    assert result.recall is not None
    assert result.recall >= 0.8
    assert result.precision_door is not None
    assert result.precision_door >= 0.8


def test_360_lidar_places_transitions_at_doors() -> None:
    """A 360° sensor keeps seeing the old room behind it: late, but at the right place."""
    result = _pooled([(0, 6)], 360.0)
    _report(f"360° lidar, laser profile: {result.describe()}")
    assert result.recall_boundary is not None
    assert result.recall_boundary >= 0.8
    assert result.precision_door is not None
    assert result.precision_door >= 0.8


@pytest.mark.xfail(
    reason="360° sensor: the old room stays in view through the door, so the CovRate needs "
    "~10-15 frames in the new room before Ncut <= 0.25 (boundary_seq is still at the door)",
    strict=True,
)
def test_360_lidar_detects_within_tolerance() -> None:
    result = _pooled([(0, 6)], 360.0)
    assert result.recall is not None
    assert result.recall >= 0.8

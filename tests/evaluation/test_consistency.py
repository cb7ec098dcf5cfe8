"""Scoring transitions against a tiny hand-made ground truth, and on a simulated run."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import pytest

from lessmap.core import PartitionParams
from lessmap.evaluation.data.simrun import load_truth
from lessmap.evaluation.scores.consistency import (
    Detection,
    fixed_feature_detections,
    lessmap_detections,
    score,
)
from lessmap.files.frames import FrameRow, read_frames
from lessmap.sim import groundtruth
from lessmap.sim.building import Door
from lessmap.sim.simulator import RoomChange, SimTruth, TruthRow

if TYPE_CHECKING:
    from pathlib import Path

    from lessmap.sim.simulator import SimRun


def corridor_truth() -> SimTruth:
    """Robot a walks x = 0..14 and back along y = 0; the door between rooms 0/1 is at 9.5."""
    rows = []
    for seq in range(30):
        x = float(seq if seq <= 14 else 28 - seq)
        rows.append(TruthRow("a", seq, seq / 2, 1 if x >= 9.5 else 0, x, 0.0, 7, abs(x - 9.5)))
    rows += [TruthRow("b", seq, seq / 2, 0, 0.0, 5.0, 7, math.hypot(9.5, 5.0)) for seq in range(5)]
    changes = (RoomChange("a", 10, 0, 1, 7), RoomChange("a", 19, 1, 0, 7))
    door = Door(7, 9.5, 0.0, (0, 1), 1.0, vertical=True)
    return SimTruth(rows=tuple(rows), doors=(door,), changes=changes)


def test_counts_by_hand() -> None:
    detections = [Detection("a", 13, 10), Detection("a", 22, 19), Detection("a", 5, 4)]
    result = score(corridor_truth(), detections, tolerance_frames=3, door_distance_m=2.0)
    assert (result.changes, result.transitions) == (2, 3)
    assert (result.recall, result.recall_boundary, result.recall_any) == (1.0, 1.0, 1.0)
    assert result.precision == pytest.approx(2 / 3)  # seq 5 is 5 frames from the change at 10
    assert result.precision_boundary == pytest.approx(2 / 3)
    assert result.precision_door == pytest.approx(2 / 3)  # x = 10 and 9 are 0.5 m from it
    assert (result.latency_mean, result.latency_median, result.latency_max) == (3.0, 3.0, 3)
    (door,) = result.doors
    assert (door.door, door.to_room, door.crossings, door.matched) == (7, None, 2, 2)
    assert door.boundary_mean_m == pytest.approx(1.0)  # boundaries at x = 10 and x = 9
    assert door.seq_mean_m == pytest.approx(7.0)  # detections at x = 13 and x = 6
    assert door.boundary_to_door_m == pytest.approx(0.5)
    assert result.spread() == pytest.approx((1.0, 1.0))
    assert result.spread(at="seq") == pytest.approx((7.0, 7.0))
    assert [(p.to_room, p.crossings) for p in result.passages] == [(0, 1), (1, 1)]
    assert result.spread(passages=True) is None  # each direction was crossed once
    assert result.as_dict()["doors"][0]["matched"] == 2


def test_late_missed_and_foreign_detections() -> None:
    # a@10 found only 8 frames late (outside ±3), a@19 never; b has no change at all.
    detections = [Detection("a", 18, 17), Detection("b", 2, 1)]
    result = score(corridor_truth(), detections, tolerance_frames=3)
    assert result.recall == 0.0
    assert result.recall_any == 0.5
    assert result.latency_max == 8
    assert result.precision == 0.5  # a@18 lies within ±3 of the change at 19; b@2 near none
    assert result.doors[0].matched == 1
    assert result.doors[0].boundary_mean_m is None  # one point: no spread


def test_nothing_to_score() -> None:
    empty = SimTruth(rows=(), doors=(), changes=())
    result = score(empty, [])
    assert (result.recall, result.precision, result.precision_door) == (None, None, None)
    assert result.latency_mean is None
    assert result.spread() is None


def test_bad_inputs_are_named() -> None:
    with pytest.raises(ValueError, match="tolerance_frames"):
        score(corridor_truth(), [], tolerance_frames=-1)
    with pytest.raises(ValueError, match="robot 'a' at seq 99"):
        score(corridor_truth(), [Detection("a", 12, 99)])


def test_fixed_feature_detections_mark_each_new_submap() -> None:
    frames = [FrameRow(robot, k, float(k), (k,), None) for robot in ("r", "s") for k in range(7)]
    found = fixed_feature_detections(frames, 3)
    assert [(d.robot, d.seq, d.boundary_seq) for d in found] == [
        ("r", 3, 3),
        ("r", 6, 6),
        ("s", 3, 3),
        ("s", 6, 6),
    ]
    assert {d.reason for d in found} == {"FIXED"}


def test_lessmap_on_a_simulated_run(sim_run: SimRun, sim_frames: Path) -> None:
    truth = load_truth(sim_frames)
    frames = list(read_frames(sim_frames))
    found = lessmap_detections(frames, PartitionParams.from_profile("laser"))
    assert {d.robot for d in found} <= {"robot0", "robot1"}
    assert all(d.boundary_seq <= d.seq for d in found)
    result = score(truth, found, method="lessmap")
    assert result.changes == len(sim_run.room_changes)
    assert result.recall_boundary is not None
    assert result.recall_boundary >= 0.6
    assert result.precision_door is not None
    assert result.precision_door >= 0.8
    assert {s.door for s in result.doors} <= {d.id for d in sim_run.building.doors}


def test_figures_are_those_of_the_simulator_scorer(sim_frames: Path) -> None:
    truth = load_truth(sim_frames)
    found = lessmap_detections(read_frames(sim_frames), PartitionParams.from_profile("laser"))
    result = score(truth, found, tolerance_frames=4, door_distance_m=1.5)
    by_robot: dict[str, list[Detection]] = {}
    for detection in found:
        by_robot.setdefault(detection.robot, []).append(detection)
    doors = [(door.x, door.y) for door in truth.doors]
    expected = groundtruth.score(
        truth.changes,
        by_robot,
        positions=truth.positions(),
        doors=doors,
        tolerance_frames=4,
        distance_m=1.5,
    )
    names = (
        *("recall", "recall_boundary", "recall_any", "precision", "precision_boundary"),
        *("precision_door", "latency_mean", "latency_max", "changes", "transitions"),
    )
    assert {n: getattr(result, n) for n in names} == {n: getattr(expected, n) for n in names}
    assert result.latency_median == expected.latency_median
    assert result.tolerance_frames == 4
    assert result.door_distance_m == 1.5


def test_a_building_without_doors_has_no_door_figure() -> None:
    truth = corridor_truth()
    result = score(replace(truth, doors=()), [Detection("a", 13, 10)], tolerance_frames=3)
    assert result.precision_door is None  # not 0: there is no door to be near
    assert result.doors == ()
    assert result.recall == 0.5
    assert score(truth, [Detection("a", 13, 10)], tolerance_frames=3).precision_door == 1.0

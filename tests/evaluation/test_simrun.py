"""Reading a simulated run's files: truth, building, and the synthesized SLAM problem."""

from __future__ import annotations

import json
import shutil
from typing import TYPE_CHECKING

import numpy as np
import pytest

from lessmap.errors import DatasetError
from lessmap.evaluation.data.simrun import (
    choose_robot,
    is_sim_run,
    load_for_eval,
    load_truth,
    sim_problem,
)
from lessmap.evaluation.scores.infoloss import (
    information_loss,
    landmark_information,
    landmark_submaps,
)
from lessmap.files.frames import FrameRow
from tests.evaluation.helpers import write_dataset

if TYPE_CHECKING:
    from pathlib import Path

    from lessmap.sim.simulator import SimRun


def copy_run(sim_frames: Path, folder: Path) -> Path:
    for suffix in (".frames.jsonl", ".truth.jsonl", ".building.json"):
        shutil.copy(sim_frames.with_name("sim" + suffix), folder / ("sim" + suffix))
    return folder / "sim.frames.jsonl"


def test_truth_matches_the_simulator(sim_run: SimRun, sim_frames: Path) -> None:
    truth = load_truth(sim_frames)
    assert len(truth.rows) == len(sim_run.truth)
    assert [(c.robot, c.seq, c.door) for c in truth.changes] == [
        (c.robot, c.seq, c.door) for c in sim_run.room_changes
    ]
    assert {d.id: (d.x, d.y) for d in truth.doors} == {
        d.id: (d.x, d.y) for d in sim_run.building.doors
    }
    assert len(truth.landmarks) == len(sim_run.building.landmarks)
    assert truth.walls
    assert truth.rows == tuple(sim_run.truth)  # the simulator's own types, read back


def test_room_changes_fall_back_to_the_truth_rows(sim_frames: Path, tmp_path: Path) -> None:
    frames = copy_run(sim_frames, tmp_path)
    building = tmp_path / "sim.building.json"
    document = json.loads(building.read_text())
    listed = load_truth(frames).changes
    del document["room_changes"]
    building.write_text(json.dumps(document))
    derived = load_truth(frames).changes
    assert [(c.robot, c.seq, c.from_room, c.to_room) for c in derived] == [
        (c.robot, c.seq, c.from_room, c.to_room) for c in listed
    ]
    assert {c.door for c in derived} <= {d.id for d in load_truth(frames).doors}


def test_missing_or_broken_files_are_named(sim_frames: Path, tmp_path: Path) -> None:
    frames = copy_run(sim_frames, tmp_path)
    (tmp_path / "sim.truth.jsonl").write_text('{"robot": "robot0"}\n')
    with pytest.raises(DatasetError, match=r"sim\.truth\.jsonl:1"):
        load_truth(frames)
    shutil.copy(sim_frames.with_name("sim.truth.jsonl"), tmp_path / "sim.truth.jsonl")
    (tmp_path / "sim.building.json").write_text("{")
    with pytest.raises(DatasetError, match=r"sim\.building\.json: not JSON"):
        load_truth(frames)
    (tmp_path / "sim.building.json").write_text('{"rooms": []}')
    with pytest.raises(DatasetError, match=r"sim\.building\.json: unexpected layout"):
        load_truth(frames)
    (tmp_path / "sim.building.json").unlink()
    with pytest.raises(DatasetError, match=r"sim\.building\.json not found"):
        load_truth(frames)


def test_recorded_data_set_is_not_a_sim_run(tmp_path: Path) -> None:
    frames = write_dataset(tmp_path)
    assert not is_sim_run(frames)
    assert choose_robot(frames, None) is None
    assert load_for_eval(frames).note == ""


def test_sim_problem_measures_e(sim_frames: Path) -> None:
    assert is_sim_run(sim_frames)
    assert choose_robot(sim_frames, None) == "robot0"
    dataset = load_for_eval(sim_frames)
    assert dataset.robot == "robot0"
    assert "synthesized" in dataset.note
    problem = dataset.problem
    truth = load_truth(sim_frames)
    expected = np.asarray([truth.landmarks[int(i)] for i in problem.landmark_ids])
    np.testing.assert_allclose(problem.landmarks, expected)
    assert problem.odo_from.size == len(dataset.frames) - 1
    info = landmark_information(problem)
    frames = [f.features for f in dataset.frames]
    halves = np.repeat([0, 1], [len(frames) // 2, len(frames) - len(frames) // 2])
    assert 0.0 < information_loss(info, landmark_submaps(frames, halves)) < 1.0


def test_sim_problem_rejects_what_it_cannot_place() -> None:
    with pytest.raises(DatasetError, match="pose"):
        sim_problem([FrameRow("r", 0, 0.0, (1,), None)], {1: (0.0, 0.0)})
    with pytest.raises(DatasetError, match=r"\[2\]"):
        sim_problem([FrameRow("r", 0, 0.0, (2,), (0.0, 0.0, 0.0))], {1: (0.0, 0.0)})

"""Loading frames with their edges and odometry as a linearized SLAM problem."""

from __future__ import annotations

import json
import re
from typing import TYPE_CHECKING

import numpy as np
import pytest

from lessmap.errors import DatasetError
from lessmap.evaluation.data.dataset import companion_path, load_dataset
from tests.evaluation.helpers import two_rooms, write_dataset

if TYPE_CHECKING:
    from pathlib import Path


def test_load_synthetic_dataset(tmp_path: Path) -> None:
    dataset = load_dataset(write_dataset(tmp_path))
    poses, marks, seen = two_rooms()
    problem = dataset.problem
    assert (dataset.name, dataset.robot, len(dataset.frames)) == ("rooms", "r1", len(poses))
    assert problem.landmark_ids.tolist() == sorted(marks)
    expected = np.asarray([marks[int(i)] for i in problem.landmark_ids])
    np.testing.assert_allclose(problem.landmarks, expected, atol=1e-12)  # pose ⊕ measurement
    assert problem.obs_pose.size == sum(len(f) for f in seen)
    assert problem.odo_from.tolist() == list(range(len(poses) - 1))
    assert problem.unit_information_edges == 0


def test_null_information_is_unit_and_counted(tmp_path: Path) -> None:
    problem = load_dataset(write_dataset(tmp_path, unit_edges=True)).problem
    assert problem.unit_information_edges == problem.obs_pose.size
    np.testing.assert_array_equal(problem.obs_information[0], [1.0, 0.0, 1.0])


@pytest.mark.parametrize("kind", ["edges", "odometry"])
def test_missing_companion_is_named(tmp_path: Path, kind: str) -> None:
    frames = write_dataset(tmp_path)
    (tmp_path / f"rooms.{kind}.jsonl").unlink()
    with pytest.raises(DatasetError, match=re.escape(f"rooms.{kind}.jsonl not found")):
        load_dataset(frames)


def test_frames_file_name_must_end_in_frames_jsonl(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="must end in"):
        companion_path(tmp_path / "rooms.jsonl", "edges")


def test_pose_ids_must_enumerate_the_frames(tmp_path: Path) -> None:
    frames = write_dataset(tmp_path)
    odometry = tmp_path / "rooms.odometry.jsonl"
    lines = odometry.read_text().splitlines()
    extra = json.loads(lines[-1]) | {"from_pose_id": 99999, "to_pose_id": 100000}
    odometry.write_text("\n".join([*lines, json.dumps(extra)]) + "\n")
    with pytest.raises(DatasetError, match="do not enumerate"):
        load_dataset(frames)


def test_several_robots_need_a_choice(tmp_path: Path) -> None:
    frames = write_dataset(tmp_path)
    line = json.loads(frames.read_text().splitlines()[0]) | {"robot": "r2"}
    frames.write_text(frames.read_text() + json.dumps(line) + "\n")
    with pytest.raises(DatasetError, match="choose one"):
        load_dataset(frames)
    assert load_dataset(frames, robot="r1").robot == "r1"

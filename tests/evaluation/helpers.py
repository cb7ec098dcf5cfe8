"""A synthetic two-room world written in the neutral data-set format, and small problems."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import numpy as np

from lessmap.evaluation.data.dataset import SlamProblem, first_sighting

if TYPE_CHECKING:
    from pathlib import Path

ODOMETRY_INFORMATION = [400.0, 0.0, 0.0, 400.0, 0.0, 900.0]


def two_rooms(
    frames: int = 60, landmarks_per_room: int = 10
) -> tuple[list[tuple[float, float, float]], dict[int, tuple[float, float]], list[list[int]]]:
    """Return poses, landmarks and frames of a robot driving from room A (x < 10) into B.

    The robot sees the landmarks of its own room within 2.5 m in x: the stream splits into
    two areas with no common feature at the door.
    """
    room_a = np.linspace(0.0, 9.0, landmarks_per_room)
    room_b = np.linspace(11.0, 20.0, landmarks_per_room)
    marks: dict[int, tuple[float, float]] = {}
    for k, x in enumerate([*room_a, *room_b]):
        marks[k + 1] = (float(x), 2.0 if k % 2 else -2.0)
    poses = [
        (20.6 * k / (frames - 1), 0.1 * math.sin(k), 0.05 * math.cos(k)) for k in range(frames)
    ]
    seen = []
    for x, _, _ in poses:
        room = x < 10.0
        seen.append(
            [lid for lid, (lx, _) in marks.items() if (lx < 10.0) == room and abs(lx - x) <= 2.5]
        )
    return poses, marks, seen


def write_dataset(folder: Path, name: str = "rooms", *, unit_edges: bool = False) -> Path:
    """Write ``<name>.frames/edges/odometry.jsonl`` of ``two_rooms``; return the frames path."""
    poses, marks, seen = two_rooms()
    pose_ids = [10 * k + 3 for k in range(len(poses))]  # vertex ids need not be the seq
    frame_lines, edge_lines, odo_lines = [], [], []
    for seq, (pose, features) in enumerate(zip(poses, seen, strict=True)):
        frame_lines.append(
            {"robot": "r1", "seq": seq, "stamp": float(seq), "features": features, "pose": pose}
        )
        x, y, theta = pose
        c, s = math.cos(theta), math.sin(theta)
        for lid in features:
            dx, dy = marks[lid][0] - x, marks[lid][1] - y
            edge_lines.append(
                {
                    "robot": "r1",
                    "seq": seq,
                    "pose_id": pose_ids[seq],
                    "landmark_id": lid,
                    "measurement": [c * dx + s * dy, -s * dx + c * dy],
                    "information": None if unit_edges else [50.0, 0.0, 50.0],
                }
            )
        if seq:
            (x0, y0, t0), (x1, y1, t1) = poses[seq - 1], pose
            c0, s0 = math.cos(t0), math.sin(t0)
            odo_lines.append(
                {
                    "from_pose_id": pose_ids[seq - 1],
                    "to_pose_id": pose_ids[seq],
                    "measurement": [
                        c0 * (x1 - x0) + s0 * (y1 - y0),
                        -s0 * (x1 - x0) + c0 * (y1 - y0),
                        t1 - t0,
                    ],
                    "information": ODOMETRY_INFORMATION,
                }
            )
    for kind, lines in (("frames", frame_lines), ("edges", edge_lines), ("odometry", odo_lines)):
        text = "".join(json.dumps(line) + "\n" for line in lines)
        (folder / f"{name}.{kind}.jsonl").write_text(text, encoding="utf-8")
    return folder / f"{name}.frames.jsonl"


def small_problem(
    poses: list[tuple[float, float, float]],
    marks: list[tuple[float, float]],
    sightings: list[tuple[int, int]],
    *,
    rng: np.random.Generator | None = None,
) -> SlamProblem:
    """Build a problem directly: poses chained by odometry, (pose, landmark) sightings.

    Information is unit, or random SPD when ``rng`` is given. Landmark IDs are 100 + index.
    """
    pose_index = np.asarray([p for p, _ in sightings], dtype=np.int64)
    mark_index = np.asarray([m for _, m in sightings], dtype=np.int64)
    pose_arr = np.asarray(poses, dtype=np.float64)
    mark_arr = np.asarray(marks, dtype=np.float64)
    t = pose_arr[pose_index, 2]
    d = mark_arr[mark_index] - pose_arr[pose_index, :2]
    meas = np.column_stack(
        [np.cos(t) * d[:, 0] + np.sin(t) * d[:, 1], -np.sin(t) * d[:, 0] + np.cos(t) * d[:, 1]]
    )

    def info(dim: int, count: int) -> np.ndarray:
        rows, cols = np.triu_indices(dim)
        if rng is None:
            return np.tile(np.eye(dim)[rows, cols], (count, 1))
        out = []
        for _ in range(count):
            a = rng.normal(size=(dim, dim))
            out.append((a @ a.T + dim * np.eye(dim))[rows, cols])
        return np.asarray(out).reshape(count, -1)

    m = len(poses)
    assert set(mark_index.tolist()) == set(range(len(marks))), "every landmark needs a sighting"
    return SlamProblem(
        poses=pose_arr,
        landmark_ids=100 + np.arange(len(marks), dtype=np.int64),
        landmarks=first_sighting(pose_arr, pose_index, mark_index, meas, len(marks)),
        obs_pose=pose_index,
        obs_landmark=mark_index,
        obs_information=info(2, len(sightings)),
        odo_from=np.arange(m - 1, dtype=np.int64),
        odo_to=np.arange(1, m, dtype=np.int64),
        odo_information=info(3, m - 1),
        unit_information_edges=0,
    )

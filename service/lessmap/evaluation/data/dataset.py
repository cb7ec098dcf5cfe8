"""Load a data set for evaluation: frames plus the 2-D SLAM problem of its companion files.

Rules of this file (formats: ``../shared/datasets/README.md``; in full:
``docs/design/evaluation.md``):

1. Companions are found next to ``<name>.frames.jsonl`` by name (``.edges.jsonl``,
   ``.odometry.jsonl``); a missing one is a ``DatasetError`` that names the path.
2. One robot at a time: a file with several robots needs ``robot=``.
3. Pose IDs sorted ascending enumerate the frames in file order; every edge is checked.
4. Measurements are g2o's EDGE_SE2_XY and EDGE_SE2, information as the upper triangle,
   row-major; where it is null, unit information is used and counted.
5. The linearization point is each frame's ``pose``; a landmark starts at its first sighting.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.errors import DatasetError
from lessmap.files.frames import read_frames, read_objects

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from lessmap.files.frames import FrameRow

FRAMES_SUFFIX = ".frames.jsonl"
_UNIT_LANDMARK = (1.0, 0.0, 1.0)
_UNIT_ODOMETRY = (1.0, 0.0, 0.0, 1.0, 0.0, 1.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class SlamProblem:
    """A 2-D pose–landmark problem linearized at given poses (m poses, n landmarks, k edges).

    Pose i is frame i of the robot's frames, in file order.
    """

    poses: NDArray[np.float64]  # (m, 3) x, y, θ: the linearization point
    landmark_ids: NDArray[np.int64]  # (n,) ascending
    landmarks: NDArray[np.float64]  # (n, 2) x, y from the first sighting
    obs_pose: NDArray[np.int64]  # (k,) pose index of each landmark measurement
    obs_landmark: NDArray[np.int64]  # (k,) landmark index
    obs_information: NDArray[np.float64]  # (k, 3) upper triangle xx, xy, yy
    odo_from: NDArray[np.int64]  # (q,) pose index
    odo_to: NDArray[np.int64]  # (q,)
    odo_information: NDArray[np.float64]  # (q, 6) upper triangle of the 3×3 matrix
    unit_information_edges: int  # edges (either kind) whose information was null


@dataclass(frozen=True, slots=True)
class Dataset:
    """The frames of one robot and, when loaded, its SLAM problem."""

    name: str
    robot: str
    frames: tuple[FrameRow, ...]
    problem: SlamProblem
    note: str = ""  # where H comes from, when not from the data set's own files


def companion_path(frames_path: Path, kind: str) -> Path:
    """Return ``<name>.<kind>.jsonl`` next to ``<name>.frames.jsonl``.

    Raises:
        DatasetError: the frames file name does not end in ``.frames.jsonl`` or the
            companion file does not exist.
    """
    if not frames_path.name.endswith(FRAMES_SUFFIX):
        msg = f"{frames_path}: a frames file name must end in {FRAMES_SUFFIX}"
        raise DatasetError(msg)
    path = frames_path.with_name(frames_path.name[: -len(FRAMES_SUFFIX)] + f".{kind}.jsonl")
    if not path.is_file():
        msg = f"{path} not found: the information loss needs the {kind} next to the frames file"
        raise DatasetError(msg)
    return path


def _json_lines(path: Path) -> list[dict[str, Any]]:
    return [row for _where, row in read_objects(path)]


def _vector(row: dict[str, Any], key: str, size: int, where: str) -> tuple[float, ...]:
    value = row.get(key)
    if (
        not isinstance(value, list)
        or len(value) != size
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        msg = f"{where}: {key!r} must be a list of {size} numbers, got {value!r}"
        raise DatasetError(msg)
    return tuple(float(v) for v in value)


def load_frames(frames_path: Path, robot: str | None = None) -> tuple[str, tuple[FrameRow, ...]]:
    """Read the frames of one robot (rule 2); return the robot and its frames in order."""
    rows = list(read_frames(frames_path))
    robots = sorted({row.robot for row in rows})
    if not rows:
        msg = f"{frames_path}: holds no frames"
        raise DatasetError(msg)
    if robot is None:
        if len(robots) > 1:
            msg = f"{frames_path.name} holds robots {', '.join(robots)}; choose one"
            raise DatasetError(msg)
        robot = robots[0] if robots else ""
    frames = tuple(row for row in rows if row.robot == robot)
    if not frames:
        msg = f"{frames_path.name}: no frames of robot {robot!r}; it has {', '.join(robots)}"
        raise DatasetError(msg)
    return robot, frames


def load_dataset(frames_path: Path, robot: str | None = None) -> Dataset:
    """Read frames, edges and odometry of one robot and build its SLAM problem (rules 1-5).

    Raises:
        DatasetError: a companion file is missing or malformed, a frame has no pose, or
            the pose IDs do not match the frames.
    """
    robot, frames = load_frames(frames_path, robot)
    edges = _json_lines(companion_path(frames_path, "edges"))
    odometry = _json_lines(companion_path(frames_path, "odometry"))
    if any(frame.pose is None for frame in frames):
        msg = f"{frames_path.name}: every frame needs a pose (the linearization point)"
        raise DatasetError(msg)
    edges = [e for e in edges if str(e.get("robot")) == robot]
    index_of_pose = _pose_indices(frames_path.name, len(frames), edges, odometry)
    index_of_seq = {frame.seq: i for i, frame in enumerate(frames)}
    poses = np.array([frame.pose for frame in frames], dtype=np.float64).reshape(-1, 3)

    obs_pose, obs_landmark, measurements, obs_info, unit_obs = [], [], [], [], 0
    for number, edge in enumerate(edges, start=1):
        where = f"edges line {number}"
        pose = index_of_pose[edge["pose_id"]]
        landmark = edge.get("landmark_id")
        if index_of_seq.get(edge.get("seq")) != pose:  # type: ignore[arg-type]
            msg = f"{where}: seq {edge.get('seq')} and pose_id {edge['pose_id']} disagree"
            raise DatasetError(msg)
        if not isinstance(landmark, int) or isinstance(landmark, bool):
            msg = f"{where}: landmark_id must be an integer, got {landmark!r}"
            raise DatasetError(msg)
        obs_pose.append(pose)
        obs_landmark.append(landmark)
        measurements.append(_vector(edge, "measurement", 2, where))
        obs_info.append(_information(edge, _UNIT_LANDMARK, where))
        unit_obs += edge.get("information") is None

    odo_from, odo_to, odo_info, unit_odo = [], [], [], 0
    for number, row in enumerate(odometry, start=1):
        where = f"odometry line {number}"
        odo_from.append(index_of_pose[row["from_pose_id"]])
        odo_to.append(index_of_pose[row["to_pose_id"]])
        _vector(row, "measurement", 3, where)  # checked, unused: H does not depend on it
        odo_info.append(_information(row, _UNIT_ODOMETRY, where))
        unit_odo += row.get("information") is None

    ids, landmark_index = np.unique(np.asarray(obs_landmark, dtype=np.int64), return_inverse=True)
    pose_index = np.asarray(obs_pose, dtype=np.int64)
    measured = np.asarray(measurements, dtype=np.float64).reshape(-1, 2)
    problem = SlamProblem(
        poses=poses,
        landmark_ids=ids,
        landmarks=first_sighting(poses, pose_index, landmark_index, measured, ids.size),
        obs_pose=pose_index,
        obs_landmark=landmark_index.astype(np.int64),
        obs_information=np.asarray(obs_info, dtype=np.float64).reshape(-1, 3),
        odo_from=np.asarray(odo_from, dtype=np.int64),
        odo_to=np.asarray(odo_to, dtype=np.int64),
        odo_information=np.asarray(odo_info, dtype=np.float64).reshape(-1, 6),
        unit_information_edges=unit_obs + unit_odo,
    )
    name = frames_path.name[: -len(FRAMES_SUFFIX)]
    return Dataset(name=name, robot=robot, frames=frames, problem=problem)


def _pose_indices(
    name: str, frame_count: int, edges: list[dict[str, Any]], odometry: list[dict[str, Any]]
) -> dict[int, int]:
    """Map pose IDs to frame indices (rule 3)."""
    raw_ids = {e.get("pose_id") for e in edges}
    raw_ids |= {o.get(k) for o in odometry for k in ("from_pose_id", "to_pose_id")}
    pose_ids = {p for p in raw_ids if isinstance(p, int) and not isinstance(p, bool)}
    if len(pose_ids) != len(raw_ids) or len(pose_ids) != frame_count:
        msg = f"{name}: the {len(raw_ids)} pose ids of edges and odometry do not enumerate "
        msg += f"the {frame_count} frames (rule 3 of lessmap.evaluation.data.dataset)"
        raise DatasetError(msg)
    return {pose_id: i for i, pose_id in enumerate(sorted(pose_ids))}


def _information(row: dict[str, Any], unit: tuple[float, ...], where: str) -> tuple[float, ...]:
    if row.get("information") is None:
        return unit
    return _vector(row, "information", len(unit), where)


def first_sighting(
    poses: NDArray[np.float64],
    obs_pose: NDArray[np.int64],
    obs_landmark: NDArray[np.int64],
    measurements: NDArray[np.float64],
    count: int,
) -> NDArray[np.float64]:
    """Return each landmark's position pose ⊕ measurement at its earliest sighting, (n, 2)."""
    order = np.lexsort((np.arange(obs_pose.size), obs_pose))  # by pose, then file order
    landmarks = np.full((count, 2), np.nan)
    seen_first = np.unique(obs_landmark[order], return_index=True)[1]
    first = order[seen_first]
    x, y, theta = poses[obs_pose[first]].T
    cos, sin = np.cos(theta), np.sin(theta)
    mx, my = measurements[first].T
    landmarks[obs_landmark[first]] = np.column_stack(
        [x + cos * mx - sin * my, y + sin * mx + cos * my]
    )
    return landmarks

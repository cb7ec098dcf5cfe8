"""A simulated run as a data set: ground truth, and a SLAM problem to measure e.

Rules of this file (the simulator's formats: ``lessmap.sim.simulator.write_run``):

1. A frames file is a simulated run when ``<name>.truth.jsonl`` lies next to it.
2. The truth is the simulator's ``SimTruth``; a missing or malformed file is a
   ``DatasetError``.
3. The simulator writes no edges or odometry: ``sim_problem`` builds them from the true
   poses and landmarks with fixed information (a laser at ~5 cm, odometry at ~1 cm and ~1°
   per 0.25 m step, a ratio close to DLR's); e depends on that ratio, so the report says
   when H was synthesized this way.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lessmap.errors import DatasetError
from lessmap.evaluation.data.dataset import (
    FRAMES_SUFFIX,
    Dataset,
    SlamProblem,
    load_dataset,
    load_frames,
)
from lessmap.files.frames import read_frames
from lessmap.sim.simulator import SimTruth, read_truth

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from lessmap.files.frames import FrameRow

SIM_LANDMARK_INFORMATION = (400.0, 0.0, 400.0)  # σ = 5 cm in x and y
SIM_ODOMETRY_INFORMATION = (10_000.0, 0.0, 0.0, 10_000.0, 0.0, 2_500.0)  # σ 1 cm, 0.02 rad
SIM_NOTE = (
    "H synthesized from the simulator's true poses and landmark positions: landmark "
    "information 400·I (σ 5 cm), odometry diag(1e4, 1e4, 2500) per frame step"
)


def sibling(frames_path: Path, suffix: str) -> Path:
    """Return ``<name><suffix>`` next to ``<name>.frames.jsonl``."""
    if not frames_path.name.endswith(FRAMES_SUFFIX):
        msg = f"{frames_path}: a frames file name must end in {FRAMES_SUFFIX}"
        raise DatasetError(msg)
    return frames_path.with_name(frames_path.name[: -len(FRAMES_SUFFIX)] + suffix)


def is_sim_run(frames_path: Path) -> bool:
    """Whether the frames file has a ground truth file next to it (rule 1)."""
    return (
        frames_path.name.endswith(FRAMES_SUFFIX) and sibling(frames_path, ".truth.jsonl").is_file()
    )


def load_truth(frames_path: Path) -> SimTruth:
    """Read the truth and building files next to the frames file (``lessmap.sim`` reads them).

    Raises:
        DatasetError: a file is missing or malformed.
    """
    for suffix in (".truth.jsonl", ".building.json"):
        path = sibling(frames_path, suffix)
        if not path.is_file():
            msg = f"{path} not found: the consistency scores need the simulator's files"
            raise DatasetError(msg)
    try:
        return read_truth(frames_path)
    except (OSError, ValueError) as exc:
        raise DatasetError(str(exc)) from exc


def sim_problem(
    frames: Sequence[FrameRow], landmarks: dict[int, tuple[float, float]]
) -> SlamProblem:
    """Build one robot's SLAM problem from true poses and landmark positions (rule 3).

    Raises:
        DatasetError: a frame has no pose, or sees a landmark the building does not list.
    """
    if any(frame.pose is None for frame in frames):
        msg = "every frame of a simulated run needs its pose"
        raise DatasetError(msg)
    seen = sorted({f for frame in frames for f in frame.features})
    unknown = [f for f in seen if f not in landmarks]
    if unknown:
        msg = f"landmarks {unknown[:5]} are seen but not in the building file"
        raise DatasetError(msg)
    index = {lid: i for i, lid in enumerate(seen)}
    obs = [(k, index[f]) for k, frame in enumerate(frames) for f in sorted(set(frame.features))]
    poses = np.asarray([frame.pose for frame in frames], dtype=np.float64).reshape(-1, 3)
    steps = max(len(frames) - 1, 0)
    return SlamProblem(
        poses=poses,
        landmark_ids=np.asarray(seen, dtype=np.int64),
        landmarks=np.asarray([landmarks[lid] for lid in seen], dtype=np.float64).reshape(-1, 2),
        obs_pose=np.asarray([k for k, _ in obs], dtype=np.int64),
        obs_landmark=np.asarray([i for _, i in obs], dtype=np.int64),
        obs_information=np.tile(SIM_LANDMARK_INFORMATION, (len(obs), 1)),
        odo_from=np.arange(steps, dtype=np.int64),
        odo_to=np.arange(1, steps + 1, dtype=np.int64),
        odo_information=np.tile(SIM_ODOMETRY_INFORMATION, (steps, 1)),
        unit_information_edges=0,
    )


def load_for_eval(frames_path: Path, robot: str | None = None) -> Dataset:
    """Load a data set for ``lessmap eval``: a recorded one, or a simulated run.

    A simulated run (rule 1) without edges and odometry gets ``sim_problem``; with several
    robots and no ``robot`` it takes the first robot (sorted by name).
    """
    robot = choose_robot(frames_path, robot)
    if not is_sim_run(frames_path) or sibling(frames_path, ".edges.jsonl").is_file():
        return load_dataset(frames_path, robot)
    robot, frames = load_frames(frames_path, robot)
    problem = sim_problem(frames, load_truth(frames_path).landmarks)
    name = frames_path.name[: -len(FRAMES_SUFFIX)]
    return Dataset(name=name, robot=robot, frames=frames, problem=problem, note=SIM_NOTE)


def choose_robot(frames_path: Path, robot: str | None) -> str | None:
    """Return ``robot``, or for a simulated run without one its first robot (by name)."""
    if robot is not None or not is_sim_run(frames_path):
        return robot
    return min((row.robot for row in read_frames(frames_path)), default=None)

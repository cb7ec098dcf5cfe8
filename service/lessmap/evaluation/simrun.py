"""Read a simulated run's files: ground truth, building, and a SLAM problem to measure e.

The simulator (``lessmap.sim.simulator.write_run``, formats in its docstring) writes
``<name>.frames.jsonl``, ``<name>.truth.jsonl`` and ``<name>.building.json`` side by side.
This package may not import the client, so the files are the interface. Rules:

1. A frames file is a simulated run when ``<name>.truth.jsonl`` lies next to it.
2. Room changes come from the building file's ``room_changes`` (they name the door); a
   building file without them gives the changes of the truth rows, each at the door the
   truth row of the change frame names in ``door_near``.
3. The simulator writes no edges or odometry: ``sim_problem`` builds them from the true
   poses and the building's landmark positions, with the fixed information below (a 2-D
   laser scanner at ~5 cm, wheel odometry at ~1 cm and ~1° per 0.25 m step; the ratio of
   odometry to landmark information is close to DLR's). e depends on that ratio, so the
   report says when H was synthesized this way.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.errors import DatasetError
from lessmap.evaluation.dataset import (
    FRAMES_SUFFIX,
    Dataset,
    SlamProblem,
    load_dataset,
    load_frames,
)
from lessmap.frames_file import read_frames

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from lessmap.frames_file import FrameRow

SIM_LANDMARK_INFORMATION = (400.0, 0.0, 400.0)  # σ = 5 cm in x and y
SIM_ODOMETRY_INFORMATION = (10_000.0, 0.0, 0.0, 10_000.0, 0.0, 2_500.0)  # σ 1 cm, 0.02 rad
SIM_NOTE = (
    "H synthesized from the simulator's true poses and landmark positions: landmark "
    "information 400·I (σ 5 cm), odometry diag(1e4, 1e4, 2500) per frame step"
)


@dataclass(frozen=True, slots=True)
class TruthRow:
    """Where a robot really was at one frame (a line of ``<name>.truth.jsonl``)."""

    robot: str
    seq: int
    room: int
    x: float
    y: float
    door: int | None  # nearest door


@dataclass(frozen=True, slots=True)
class Door:
    """A door of the building: its centre (metres) and the two rooms it joins."""

    id: int
    x: float
    y: float
    rooms: tuple[int, int]


@dataclass(frozen=True, slots=True)
class RoomChange:
    """A robot entered another room; ``seq`` is its first frame there."""

    robot: str
    seq: int
    from_room: int
    to_room: int
    door: int | None


@dataclass(frozen=True, slots=True)
class SimTruth:
    """The ground truth of a simulated run."""

    rows: tuple[TruthRow, ...]
    doors: tuple[Door, ...]
    changes: tuple[RoomChange, ...]
    landmarks: dict[int, tuple[float, float]] = field(default_factory=dict)  # id → x, y
    walls: tuple[tuple[float, float, float, float], ...] = ()  # x0, y0, x1, y1 (for figures)

    def positions(self) -> dict[tuple[str, int], tuple[float, float]]:
        """Map (robot, seq) to the true position (x, y)."""
        return {(row.robot, row.seq): (row.x, row.y) for row in self.rows}


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


def _load_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        msg = f"{path.name}: not JSON ({exc.msg})"
        raise DatasetError(msg) from exc


def _truth_row(line: str, where: str) -> TruthRow:
    try:
        row = json.loads(line)
        near = row.get("door_near")
        return TruthRow(
            robot=str(row["robot"]),
            seq=int(row["seq"]),
            room=int(row["room"]),
            x=float(row["x"]),
            y=float(row["y"]),
            door=None if near is None else int(near["door"]),
        )
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        msg = f"{where}: not a truth row ({exc})"
        raise DatasetError(msg) from exc


def load_truth(frames_path: Path) -> SimTruth:
    """Read ``<name>.truth.jsonl`` and ``<name>.building.json`` next to the frames file.

    Raises:
        DatasetError: a file is missing or malformed.
    """
    truth_path = sibling(frames_path, ".truth.jsonl")
    building_path = sibling(frames_path, ".building.json")
    for path in (truth_path, building_path):
        if not path.is_file():
            msg = f"{path} not found: the consistency scores need the simulator's files"
            raise DatasetError(msg)
    with truth_path.open(encoding="utf-8") as handle:
        rows = tuple(
            _truth_row(line, f"{truth_path.name}:{number}")
            for number, line in enumerate(handle, start=1)
            if line.strip()
        )
    building = _load_json(building_path)
    try:
        doors = tuple(
            Door(
                int(d["id"]), float(d["x"]), float(d["y"]), (int(d["rooms"][0]), int(d["rooms"][1]))
            )
            for d in building.get("doors", [])
        )
        landmarks = {
            int(m["id"]): (float(m["x"]), float(m["y"])) for m in building.get("landmarks", [])
        }
        walls = tuple(
            (float(w["x0"]), float(w["y0"]), float(w["x1"]), float(w["y1"]))
            for w in building.get("walls", [])
        )
        listed = building.get("room_changes")
        changes = (
            changes_from_rows(rows)
            if listed is None
            else tuple(
                RoomChange(
                    str(c["robot"]),
                    int(c["seq"]),
                    int(c["from_room"]),
                    int(c["to_room"]),
                    None if c.get("door") is None else int(c["door"]),
                )
                for c in listed
            )
        )
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
        msg = f"{building_path.name}: unexpected layout ({exc})"
        raise DatasetError(msg) from exc
    return SimTruth(rows=rows, doors=doors, changes=changes, landmarks=landmarks, walls=walls)


def changes_from_rows(rows: Sequence[TruthRow]) -> tuple[RoomChange, ...]:
    """Derive the room changes from the truth rows (rule 2), robots apart, in seq order."""
    by_robot: dict[str, list[TruthRow]] = {}
    for row in rows:
        by_robot.setdefault(row.robot, []).append(row)
    changes = []
    for robot, items in by_robot.items():
        items.sort(key=lambda row: row.seq)
        for before, row in itertools.pairwise(items):
            if row.room != before.room:
                changes.append(RoomChange(robot, row.seq, before.room, row.room, row.door))
    return tuple(changes)


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

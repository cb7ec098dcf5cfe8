"""The files of a floor-plan run, and their reader (the formats of ``lessmap.sim``).

``<name>.frames.jsonl``
    One frame a line, robots interleaved by stamp: ``{"robot", "seq", "stamp", "features",
    "pose": [x, y, theta]}`` (metres, radians; the true pose). ``lessmap segment`` reads it.
``<name>.truth.jsonl``
    One line a frame, same order: ``{"robot", "seq", "stamp", "room", "x", "y",
    "door_near": null}``, a ``lessmap.sim.simulator.TruthRow``. ``room`` is the ground-truth
    room (1..k, numbered as ``grid.room_labels`` numbers them); 0 in a run without labels.
``<name>.floorplan.json``
    What was simulated: map, resolution, origin, labels, sensor profile, seed, speed, rate,
    robots, landmarks, rooms visited and skipped (``toured``: "squares" without labels, then
    they count the 4 m squares toured instead), metres walked, and ``room_changes:
    [{"robot", "seq", "from_room", "to_room", "x", "y"}]`` (``seq``: first frame in the new
    room; x, y: where the robot crossed).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from lessmap.floorplan.grid import FloorplanError
from lessmap.floorplan.truth import RoomChange
from lessmap.sim.simulator import TruthRow

if TYPE_CHECKING:
    from collections.abc import Mapping

    from lessmap.floorplan.grid import OccupancyGrid
    from lessmap.floorplan.simulation import FloorplanRun

__all__ = [
    "FloorplanPaths",
    "FloorplanTruth",
    "floorplan_paths",
    "read_floorplan_truth",
    "write_floorplan_run",
]

FRAMES_SUFFIX = ".frames.jsonl"


class FloorplanPaths(NamedTuple):
    """The three files of a run."""

    frames: Path
    truth: Path
    floorplan: Path


@dataclass(frozen=True, slots=True)
class FloorplanTruth:
    """The ground truth of a floor-plan run as its files hold it."""

    rows: tuple[TruthRow, ...]  # file order: robots interleaved by stamp
    changes: tuple[RoomChange, ...]
    map_path: str
    labels_path: str | None
    resolution_m: float
    sensor: str
    rooms: int
    rooms_visited: tuple[int, ...]
    rooms_skipped: tuple[int, ...]
    path_m: dict[str, float]
    document: dict[str, Any]  # the whole floorplan.json

    def changes_of(self, robot: str) -> list[RoomChange]:
        """The true room changes of one robot, in order."""
        return [change for change in self.changes if change.robot == robot]

    def positions(self) -> dict[tuple[str, int], tuple[float, float]]:
        """Map (robot, seq) to the true position (x, y), as ``SimTruth.positions`` does."""
        return {(row.robot, row.seq): (row.x, row.y) for row in self.rows}

    def room_of(self) -> dict[tuple[str, int], int]:
        """Map (robot, seq) to the true room (0: unknown, in a run without labels)."""
        return {(row.robot, row.seq): row.room for row in self.rows}


def floorplan_paths(frames_path: str | Path) -> FloorplanPaths:
    """Name the truth and floorplan files next to ``<name>.frames.jsonl``.

    Raises:
        FloorplanError: the name does not end in ``.frames.jsonl``.
    """
    frames = Path(frames_path)
    if not frames.name.endswith(FRAMES_SUFFIX):
        msg = f"{frames}: a frames file name must end in {FRAMES_SUFFIX}"
        raise FloorplanError(msg)
    stem = frames.name[: -len(FRAMES_SUFFIX)]
    return FloorplanPaths(
        frames, frames.with_name(f"{stem}.truth.jsonl"), frames.with_name(f"{stem}.floorplan.json")
    )


def write_floorplan_run(
    run: FloorplanRun,
    grid: OccupancyGrid,
    out_dir: Path,
    name: str,
    sources: Mapping[str, str | None],
) -> FloorplanPaths:
    """Write a run's three files; ``sources`` names the ``map`` and ``labels`` files.

    Raises:
        FloorplanError: the folder or a file cannot be written; the message names it.
    """
    try:
        return _write(run, grid, out_dir, name, sources)
    except OSError as exc:
        msg = f"{exc.filename or out_dir}: cannot write ({exc.strerror or exc})"
        raise FloorplanError(msg) from None


def _write(
    run: FloorplanRun,
    grid: OccupancyGrid,
    out_dir: Path,
    name: str,
    sources: Mapping[str, str | None],
) -> FloorplanPaths:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = floorplan_paths(out_dir / f"{name}{FRAMES_SUFFIX}")
    with paths.frames.open("w", encoding="utf-8") as stream:
        for frame in run.frames:
            stream.write(json.dumps(frame, separators=(",", ":")) + "\n")
    with paths.truth.open("w", encoding="utf-8") as stream:
        for row in run.truth:
            line = {
                "robot": row.robot,
                "seq": row.seq,
                "stamp": row.stamp,
                "room": row.room,
                "x": row.x,
                "y": row.y,
                "door_near": None,
            }
            stream.write(json.dumps(line, separators=(",", ":")) + "\n")
    options = run.options
    document = {
        "map": sources.get("map"),
        "labels": sources.get("labels"),
        "resolution_m": grid.resolution_m,
        "origin_xy": list(grid.origin_xy),
        "sensor": asdict(options.sensor),
        "seed": options.seed,
        "robots": options.robots,
        "robot_radius_m": options.robot_radius_m,
        "speed_m_per_frame": options.tour.speed_m_per_frame,
        "rate_hz": options.tour.rate_hz,
        "max_frames": options.tour.max_frames,
        "frames": len(run.frames),
        "landmarks": run.landmarks,
        "rooms": run.rooms,
        "toured": "rooms" if run.rooms else "squares",  # what rooms_visited/skipped count
        "rooms_visited": list(run.rooms_visited),
        "rooms_skipped": list(run.rooms_skipped),
        "path_m": run.path_m,
        "room_changes": [asdict(change) for change in run.room_changes],
    }
    paths.floorplan.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    return paths


def read_floorplan_truth(frames_path: str | Path) -> FloorplanTruth:
    """Read the truth and floorplan files next to ``<name>.frames.jsonl``.

    Raises:
        FloorplanError: a file is missing or malformed; the message names it (and the line).
    """
    paths = floorplan_paths(frames_path)
    try:
        document = json.loads(paths.floorplan.read_text(encoding="utf-8"))
        lines = paths.truth.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError as exc:
        msg = f"{exc.filename}: no such file"
        raise FloorplanError(msg) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        msg = f"{paths.floorplan}: not a floorplan run file ({exc})"
        raise FloorplanError(msg) from None
    rows = tuple(
        _truth_row(line, f"{paths.truth}:{number}")
        for number, line in enumerate(lines, start=1)
        if line.strip()
    )
    try:
        changes = tuple(
            RoomChange(
                str(c["robot"]),
                int(c["seq"]),
                int(c["from_room"]),
                int(c["to_room"]),
                float(c["x"]),
                float(c["y"]),
            )
            for c in document["room_changes"]
        )
        return FloorplanTruth(
            rows=rows,
            changes=changes,
            map_path=str(document["map"]),
            labels_path=None if document["labels"] is None else str(document["labels"]),
            resolution_m=float(document["resolution_m"]),
            sensor=str(document["sensor"]["name"]),
            rooms=int(document["rooms"]),
            rooms_visited=tuple(int(r) for r in document["rooms_visited"]),
            rooms_skipped=tuple(int(r) for r in document["rooms_skipped"]),
            path_m={str(k): float(v) for k, v in document["path_m"].items()},
            document=document,
        )
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        msg = f"{paths.floorplan}: unexpected layout ({exc!r})"
        raise FloorplanError(msg) from None


def _truth_row(line: str, where: str) -> TruthRow:
    try:
        row = json.loads(line)
        return TruthRow(
            robot=str(row["robot"]),
            seq=int(row["seq"]),
            stamp=float(row["stamp"]),
            room=int(row["room"]),
            x=float(row["x"]),
            y=float(row["y"]),
            door=None,
            door_distance_m=math.inf,
        )
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        msg = f"{where}: not a truth row ({exc!r})"
        raise FloorplanError(msg) from None

"""Read the neutral frames format (``<name>.frames.jsonl``, see the datasets README)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from lessmap.errors import DatasetError

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path


@dataclass(frozen=True, slots=True)
class FrameRow:
    """One line of a frames file."""

    robot: str
    seq: int
    stamp_s: float
    features: tuple[int, ...]
    pose: tuple[float, float, float] | None
    where: str = ""  # "file:line" when read from a file, for error messages


def parse_object_line(line: str, where: str) -> dict[str, Any]:
    """Parse one JSON-lines line that must hold an object; ``where`` names file:line."""
    try:
        row = json.loads(line)
    except json.JSONDecodeError as exc:
        msg = f"{where}: not JSON ({exc.msg})"
        raise DatasetError(msg) from exc
    if not isinstance(row, dict):
        msg = f"{where}: expected an object, got {type(row).__name__}"
        raise DatasetError(msg)
    return row


def read_objects(path: Path) -> Iterator[tuple[str, dict[str, Any]]]:
    """Yield (file:line, object) for every non-blank line of a JSON-lines file."""
    with path.open(encoding="utf-8") as handle:
        for number, line in enumerate(handle, start=1):
            if line.strip():
                where = f"{path.name}:{number}"
                yield where, parse_object_line(line, where)


def parse_frame_line(line: str, where: str) -> FrameRow:
    """Parse one JSON line; ``where`` (file:line) goes into the error message."""
    return frame_from_object(parse_object_line(line, where), where)


def frame_from_object(row: dict[str, Any], where: str) -> FrameRow:
    """Check and convert one frames-file object."""
    try:
        robot, seq, stamp, features = row["robot"], row["seq"], row["stamp"], row["features"]
    except KeyError as exc:
        msg = f"{where}: missing field {exc.args[0]!r}"
        raise DatasetError(msg) from None
    pose = row.get("pose")
    ok = (
        isinstance(robot, str | int)
        and isinstance(seq, int)
        and not isinstance(seq, bool)
        and seq >= 0
        and isinstance(stamp, int | float)
        and math.isfinite(stamp)
        and isinstance(features, list)
        and all(isinstance(f, int) and not isinstance(f, bool) for f in features)
        and (pose is None or (isinstance(pose, list) and len(pose) == 3))
    )
    if not ok:
        msg = f"{where}: fields have the wrong types (robot str, seq int >= 0, stamp number, "
        msg += "features list of int, pose [x, y, theta] or null)"
        raise DatasetError(msg)
    return FrameRow(
        robot=str(robot),
        seq=seq,
        stamp_s=float(stamp),
        features=tuple(features),
        pose=None if pose is None else (float(pose[0]), float(pose[1]), float(pose[2])),
        where=where,
    )


def read_frames(path: Path) -> Iterator[FrameRow]:
    """Yield the frames of a file in file order; blank lines are skipped.

    Raises:
        DatasetError: a line is malformed (the message names file and line).
        FileNotFoundError: the file does not exist.
    """
    for where, row in read_objects(path):
        yield frame_from_object(row, where)

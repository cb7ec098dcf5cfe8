"""Read the neutral frames format (``<name>.frames.jsonl``, see the datasets README).

Every line is checked against the limits the service enforces on the wire (the same
``WireLimits``), so a file the offline tools accept is one the service would accept too, and
every malformed line is one ``DatasetError`` naming ``FILE:LINE`` and what is wrong.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from lessmap.errors import DatasetError
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

#: Longest line read at all; a frame at the feature limit needs far less (about 80 kB).
MAX_LINE_BYTES = 16 * 1024 * 1024

_FIELDS = ("robot", "seq", "stamp", "features")


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
        msg = f"{where}: not JSON ({exc.msg} at column {exc.colno})"
        raise DatasetError(msg) from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        msg = f"{where}: not JSON ({exc})"
        raise DatasetError(msg) from None
    except RecursionError:
        msg = f"{where}: not JSON (nested too deeply)"
        raise DatasetError(msg) from None
    if not isinstance(row, dict):
        msg = f"{where}: expected an object, got {type(row).__name__}"
        raise DatasetError(msg)
    return row


def read_lines(path: Path) -> Iterator[tuple[str, str]]:
    """Yield (file:line, text) for every non-blank line of a text file in UTF-8.

    Raises:
        DatasetError: a line is not UTF-8 or longer than ``MAX_LINE_BYTES``.
    """
    with path.open("rb") as handle:
        number = 0
        while raw := handle.readline(MAX_LINE_BYTES + 1):
            number += 1
            where = f"{path}:{number}"
            if len(raw) > MAX_LINE_BYTES:
                msg = f"{where}: line longer than {MAX_LINE_BYTES} bytes"
                raise DatasetError(msg)
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                msg = f"{where}: not UTF-8 (byte 0x{raw[exc.start]:02x} at column {exc.start + 1})"
                raise DatasetError(msg) from None
            if line.strip():
                yield where, line


def read_objects(path: Path) -> Iterator[tuple[str, dict[str, Any]]]:
    """Yield (file:line, object) for every non-blank line of a JSON-lines file."""
    for where, line in read_lines(path):
        yield where, parse_object_line(line, where)


def parse_frame_line(line: str, where: str, limits: WireLimits = DEFAULT_LIMITS) -> FrameRow:
    """Parse one JSON line; ``where`` (file:line) goes into the error message."""
    return frame_from_object(parse_object_line(line, where), where, limits)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _problem(row: dict[str, Any], limits: WireLimits) -> str | None:
    """Return what is wrong with a frames-file object, or None."""
    missing = [name for name in _FIELDS if name not in row]
    if missing:
        return f"missing field {', '.join(map(repr, missing))}"
    robot, seq, features, pose = row["robot"], row["seq"], row["features"], row.get("pose")
    problem = None
    if not (isinstance(robot, str) and robot) and not _is_int(robot):
        problem = f"robot must be a non-empty string, got {robot!r}"
    elif not _is_int(seq) or seq < 0:
        problem = f"seq must be an integer >= 0, got {_short(seq)}"
    elif seq > limits.max_seq:
        problem = f"seq {seq} is above the wire limit {limits.max_seq}"
    elif not _is_number(row["stamp"]):
        problem = f"stamp must be a finite number, got {_short(row['stamp'])}"
    elif not isinstance(features, list):
        problem = f"features must be a list of integers, got {_short(features)}"
    elif len(features) > limits.max_features_per_frame:
        problem = (
            f"{len(features)} features, more than the limit of "
            f"{limits.max_features_per_frame} per frame (--max-features-per-frame)"
        )
    elif pose is not None and not (
        isinstance(pose, list) and len(pose) == 3 and all(map(_is_number, pose))
    ):
        problem = f"pose must be [x, y, theta] (finite numbers) or null, got {_short(pose)}"
    else:
        for index, feature in enumerate(features):
            if not _is_int(feature) or not 0 <= feature <= limits.max_feature_id:
                problem = (
                    f"feature {index} must be an integer in 0..{limits.max_feature_id}, "
                    f"got {_short(feature)}"
                )
                break
    return problem


def _short(value: object) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def frame_from_object(
    row: dict[str, Any], where: str, limits: WireLimits = DEFAULT_LIMITS
) -> FrameRow:
    """Check and convert one frames-file object.

    Raises:
        DatasetError: a field is missing, of the wrong type or beyond ``limits``.
    """
    problem = _problem(row, limits)
    if problem is not None:
        msg = f"{where}: {problem}"
        raise DatasetError(msg)
    pose = row.get("pose")
    return FrameRow(
        robot=str(row["robot"]),
        seq=row["seq"],
        stamp_s=float(row["stamp"]),
        features=tuple(row["features"]),
        pose=None if pose is None else (float(pose[0]), float(pose[1]), float(pose[2])),
        where=where,
    )


def read_frames(path: Path, limits: WireLimits = DEFAULT_LIMITS) -> Iterator[FrameRow]:
    """Yield the frames of a file in file order; blank lines are skipped.

    Raises:
        DatasetError: a line is malformed (the message names file and line).
        FileNotFoundError: the file does not exist.
    """
    for where, row in read_objects(path):
        yield frame_from_object(row, where, limits)

"""The neutral frames-file format (``<name>.frames.jsonl``): its rules, once, for every reader.

One JSON object per line, ``{"robot", "seq", "stamp", "features", "pose"?}`` (the shared
datasets README). A frames file is the recorded form of what robots put on the wire, so each
line is checked against the same ``WireLimits`` the service enforces: a file the offline tools
accept is one the service would accept too. Readers (``lessmap segment``'s, ``lessmap
replay``'s) raise ``FramesFileError`` with one message ``FILE:LINE: what is wrong``; pure
standard library, no numpy, so the SDK uses it too.
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

from lessmap_schemas.errors import FramesFileError

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from lessmap_schemas.limits import WireLimits

#: Longest line read at all; a frame at the feature limit needs far less (about 80 kB).
MAX_LINE_BYTES = 16 * 1024 * 1024

FIELDS = ("robot", "seq", "stamp", "features")


def read_lines(path: Path) -> Iterator[tuple[str, str]]:
    """Yield (file:line, text) for every non-blank line of a text file in UTF-8.

    Raises:
        FramesFileError: a line is not UTF-8 or longer than ``MAX_LINE_BYTES``.
        FileNotFoundError: the file does not exist.
    """
    with path.open("rb") as handle:
        number = 0
        while raw := handle.readline(MAX_LINE_BYTES + 1):
            number += 1
            where = f"{path}:{number}"
            if len(raw) > MAX_LINE_BYTES:
                msg = f"{where}: line longer than {MAX_LINE_BYTES} bytes"
                raise FramesFileError(msg)
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                msg = f"{where}: not UTF-8 (byte 0x{raw[exc.start]:02x} at column {exc.start + 1})"
                raise FramesFileError(msg) from None
            if line.strip():
                yield where, line


def parse_object_line(line: str, where: str) -> dict[str, Any]:
    """Parse one JSON-lines line that must hold an object; ``where`` names file:line.

    Raises:
        FramesFileError: not JSON, or not an object.
    """
    try:
        row = json.loads(line)
    except json.JSONDecodeError as exc:
        msg = f"{where}: not JSON ({exc.msg} at column {exc.colno})"
        raise FramesFileError(msg) from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        msg = f"{where}: not JSON ({exc})"
        raise FramesFileError(msg) from None
    except RecursionError:
        msg = f"{where}: not JSON (nested too deeply)"
        raise FramesFileError(msg) from None
    if not isinstance(row, dict):
        msg = f"{where}: expected an object, got {type(row).__name__}"
        raise FramesFileError(msg)
    return row


def frame_problem(row: dict[str, Any], limits: WireLimits) -> str | None:
    """Return what is wrong with one frames-file object under ``limits``, or None."""
    missing = [name for name in FIELDS if name not in row]
    if missing:
        return f"missing field {', '.join(map(repr, missing))}"
    robot, seq, features, pose = row["robot"], row["seq"], row["features"], row.get("pose")
    if not (isinstance(robot, str) and robot) and not _is_int(robot):
        return f"robot must be a non-empty string, got {robot!r}"
    if not _is_int(seq) or seq < 0:
        return f"seq must be an integer >= 0, got {short(seq)}"
    if seq > limits.max_seq:
        return f"seq {seq} is above the wire limit {limits.max_seq}"
    if not _is_number(row["stamp"]):
        return f"stamp must be a finite number, got {short(row['stamp'])}"
    if not isinstance(features, list):
        return f"features must be a list of integers, got {short(features)}"
    if len(features) > limits.max_features_per_frame:
        return (
            f"{len(features)} features, more than the limit of "
            f"{limits.max_features_per_frame} per frame"
        )
    if pose is not None and not (
        isinstance(pose, list) and len(pose) == 3 and all(map(_is_number, pose))
    ):
        return f"pose must be [x, y, theta] (finite numbers) or null, got {short(pose)}"
    for index, feature in enumerate(features):
        if not _is_int(feature) or not 0 <= feature <= limits.max_feature_id:
            return (
                f"feature {index} must be an integer in 0..{limits.max_feature_id}, "
                f"got {short(feature)}"
            )
    return None


def checked_frame(row: dict[str, Any], where: str, limits: WireLimits) -> dict[str, Any]:
    """Return ``row`` when it is a valid frame, else raise ``FramesFileError`` (FILE:LINE)."""
    problem = frame_problem(row, limits)
    if problem is not None:
        msg = f"{where}: {problem}"
        raise FramesFileError(msg)
    return row


def pose_of(row: dict[str, Any]) -> tuple[float, float, float] | None:
    """The checked row's pose as floats, or None."""
    pose = row.get("pose")
    return None if pose is None else (float(pose[0]), float(pose[1]), float(pose[2]))


def short(value: object) -> str:
    """A value as JSON, cut to 40 characters, for an error message."""
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


#: Covisibility needs two features in one frame: below this average, frames barely link.
MIN_MEAN_FEATURES = 2.0


def sparse_frames_warning(source: str, frames: int, features: int) -> str | None:
    """Return a one-line warning when frames hold too few features to be covisible.

    Two features seen in one frame are what links them (a CovGraph edge); with fewer than
    ``MIN_MEAN_FEATURES`` a frame on average, a segmentation is one area or hundreds,
    decided by noise. ``features`` counts every frame's features (repeats included).
    """
    if frames == 0 or features >= MIN_MEAN_FEATURES * frames:
        return None
    return (
        f"warning: {source}: its {frames} frames hold {features / frames:.2f} features on "
        f"average, fewer than {MIN_MEAN_FEATURES:g}: only features seen in the same frame "
        f"are linked, so few links decide the areas"
    )

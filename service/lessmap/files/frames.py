"""Read the neutral frames format (``<name>.frames.jsonl``, see the datasets README).

The rules are the contract's (``lessmap_schemas.framesfile``, shared with ``lessmap replay``):
every line is checked against the limits the service enforces on the wire, and every
malformed line is one ``DatasetError`` naming ``FILE:LINE`` and what is wrong.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from lessmap.errors import DatasetError
from lessmap_schemas import framesfile
from lessmap_schemas.errors import FramesFileError
from lessmap_schemas.framesfile import (
    sparse_frames_warning as sparse_frames_warning,  # re-exported: the offline tools' warning
)
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits

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
        return framesfile.parse_object_line(line, where)
    except FramesFileError as exc:
        raise DatasetError(str(exc)) from None


def read_lines(path: Path) -> Iterator[tuple[str, str]]:
    """Yield (file:line, text) for every non-blank line of a text file in UTF-8.

    Raises:
        DatasetError: a line is not UTF-8 or longer than ``MAX_LINE_BYTES``.
    """
    try:
        yield from framesfile.read_lines(path)
    except FramesFileError as exc:
        raise DatasetError(str(exc)) from None


def read_objects(path: Path) -> Iterator[tuple[str, dict[str, Any]]]:
    """Yield (file:line, object) for every non-blank line of a JSON-lines file."""
    for where, line in read_lines(path):
        yield where, parse_object_line(line, where)


def parse_frame_line(line: str, where: str, limits: WireLimits = DEFAULT_LIMITS) -> FrameRow:
    """Parse one JSON line; ``where`` (file:line) goes into the error message."""
    return frame_from_object(parse_object_line(line, where), where, limits)


def frame_from_object(
    row: dict[str, Any], where: str, limits: WireLimits = DEFAULT_LIMITS
) -> FrameRow:
    """Check and convert one frames-file object.

    Raises:
        DatasetError: a field is missing, of the wrong type or beyond ``limits``.
    """
    try:
        framesfile.checked_frame(row, where, limits)
    except FramesFileError as exc:
        raise DatasetError(str(exc)) from None
    return FrameRow(
        robot=str(row["robot"]),
        seq=row["seq"],
        stamp_s=float(row["stamp"]),
        features=tuple(row["features"]),
        pose=framesfile.pose_of(row),
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

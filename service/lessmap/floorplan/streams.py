"""A run's streams for room maps and their scores: poses, true rooms and transitions per robot.

Reads a frames file's poses, a truth file (``<name>.truth.jsonl``, one ``TruthRow`` a line:
``robot``, ``seq``, ``stamp``, ``room``, ``x``, ``y``), a ``lessmap segment`` output, or runs
a method over the frames (``paper``, ``areas``, or ``fixed``: a cut every N frames). Every
malformed input is a ``FloorplanError`` that names the file, line and value.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lessmap.floorplan.grid import FloorplanError
from lessmap.floorplan.metric import Cut, Track

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence
    from pathlib import Path

    from numpy.typing import NDArray

    from lessmap.core.areas.params import AreaParams
    from lessmap.files.frames import FrameRow

__all__ = [
    "Poses",
    "fixed_cuts",
    "frame_areas",
    "method_cuts",
    "read_poses",
    "read_tracks",
    "read_transitions",
]

METHODS = ("areas", "rooms", "paper")


@dataclass(frozen=True, slots=True)
class Poses:
    """One robot's frames in seq order: seq and position (m) of each."""

    seqs: NDArray[np.int64]
    xy: NDArray[np.float64]  # (n, 2)


def read_poses(frames: Iterable[FrameRow], source: str) -> dict[str, Poses]:
    """Group frames by robot, in seq order, with their positions.

    Raises:
        FloorplanError: a frame has no pose (a room map needs positions).
    """
    seqs: dict[str, list[int]] = {}
    xys: dict[str, list[tuple[float, float]]] = {}
    for frame in frames:
        if frame.pose is None:
            msg = (
                f"{frame.where or source}: robot {frame.robot} frame {frame.seq} has no pose; "
                "a room map needs each frame's position (pose [x, y, theta])"
            )
            raise FloorplanError(msg)
        seqs.setdefault(frame.robot, []).append(frame.seq)
        xys.setdefault(frame.robot, []).append((frame.pose[0], frame.pose[1]))
    out = {}
    for robot, robot_seqs in seqs.items():
        order = np.argsort(robot_seqs, kind="stable")
        out[robot] = Poses(
            np.asarray(robot_seqs, dtype=np.int64)[order],
            np.asarray(xys[robot], dtype=np.float64).reshape(-1, 2)[order],
        )
    return out


def read_tracks(truth: Path) -> dict[str, Track]:
    """Read a truth file: per robot, its frames' true positions and rooms in seq order.

    Raises:
        FloorplanError: the file is missing or a line is not a truth row.
    """
    rows: dict[str, list[tuple[int, float, float, int]]] = {}
    try:
        with truth.open(encoding="utf-8") as handle:
            for number, line in enumerate(handle, start=1):
                if not line.strip():
                    continue
                try:
                    row = json.loads(line)
                    rows.setdefault(str(row["robot"]), []).append(
                        (int(row["seq"]), float(row["x"]), float(row["y"]), int(row["room"]))
                    )
                except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
                    msg = f"{truth}:{number}: not a truth row ({exc.__class__.__name__}: {exc})"
                    raise FloorplanError(msg) from None
    except FileNotFoundError:
        msg = f"{truth}: no such file"
        raise FloorplanError(msg) from None
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"{truth}: cannot read ({exc.__class__.__name__})"
        raise FloorplanError(msg) from None
    tracks = {}
    for robot, items in rows.items():
        items.sort()
        table = np.asarray(items, dtype=np.float64).reshape(-1, 4)
        tracks[robot] = Track(
            table[:, 0].astype(np.int64), table[:, 1:3], table[:, 3].astype(np.int64)
        )
    return tracks


def read_transitions(path: Path) -> dict[str, list[Cut]]:
    """Read a ``lessmap segment`` output: per robot, its transitions (summary lines skipped).

    The area is ``area`` (``--method areas``) or the opened segment's id (``paper``).

    Raises:
        FloorplanError: the file is missing or a line is not a transition.
    """
    cuts: dict[str, list[Cut]] = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        msg = f"{path}: no such file"
        raise FloorplanError(msg) from None
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"{path}: cannot read ({exc.__class__.__name__})"
        raise FloorplanError(msg) from None
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            if row.get("summary"):
                continue
            area = row["area"] if "area" in row else row["opened"]["id"]
            cuts.setdefault(str(row["robot"]), []).append(
                Cut(
                    int(row["seq"]),
                    int(row["boundary_seq"]),
                    int(area),
                    row.get("revisit_of") is not None,
                )
            )
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
            msg = f"{path}:{number}: not a lessmap segment transition ({exc!r})"
            raise FloorplanError(msg) from None
    return cuts


def method_cuts(
    frames: Sequence[FrameRow], method: str, areas: AreaParams | None = None
) -> dict[str, list[Cut]]:
    """Run ``paper``, ``areas`` or ``rooms`` over the frames, per robot.

    Default parameters, but ``areas``' when given.
    """
    from lessmap.evaluation.methods import run_method

    if method not in METHODS:
        msg = f"unknown method {method!r}; choose one of {', '.join(METHODS)}"
        raise FloorplanError(msg)
    events = run_method(frames, method, areas=areas)
    return {
        robot: [Cut(e.seq, e.boundary_seq, e.area, e.revisit) for e in found]
        for robot, found in events.items()
    }


def fixed_cuts(seqs: NDArray[np.int64], length: int) -> list[Cut]:
    """The fixed-interval baseline: a new segment (and area) every ``length`` frames."""
    if length < 1:
        msg = f"fixed interval must be >= 1 frame, got {length}"
        raise FloorplanError(msg)
    return [
        Cut(int(seqs[i]), int(seqs[i]), i // length, False)
        for i in range(length, seqs.size, length)
    ]


def frame_areas(
    seqs: NDArray[np.int64], cuts: Sequence[Cut], first_area: int = 0
) -> NDArray[np.int64]:
    """Each frame's area: that of the last transition whose boundary is at or before it."""
    boundaries = np.asarray([c.boundary_seq for c in cuts], dtype=np.int64)
    order = np.argsort(boundaries, kind="stable")
    areas = np.asarray([first_area, *[cuts[i].area for i in order]], dtype=np.int64)
    return areas[np.searchsorted(boundaries[order], seqs, side="right")]

"""Replay a recorded frames file to the service: one publisher per robot in the file."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from lessmap_client.robot import RobotPublisher

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator
    from pathlib import Path

    import zenoh


class ReplayError(ValueError):
    """A frames file line is malformed (the message names file and line)."""


@dataclass(frozen=True, slots=True)
class RecordedFrame:
    """One line of a frames file (format: shared datasets README)."""

    robot: str
    seq: int
    stamp_s: float
    features: list[int]
    pose: tuple[float, float, float] | None


def read_recorded(path: Path) -> Iterator[RecordedFrame]:
    """Yield the frames of a ``.frames.jsonl`` file in file order.

    Raises:
        ReplayError: a line is not a valid frame.
    """
    with path.open(encoding="utf-8") as handle:
        for number, line in enumerate(handle, start=1):
            if line.strip():
                yield _parse(line, f"{path.name}:{number}")


def _parse(line: str, where: str) -> RecordedFrame:
    try:
        row: Any = json.loads(line)
        robot, seq, stamp, features = row["robot"], row["seq"], row["stamp"], row["features"]
        pose = row.get("pose")
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        msg = f"{where}: not a frame ({exc})"
        raise ReplayError(msg) from exc
    if not (
        isinstance(seq, int)
        and isinstance(stamp, int | float)
        and isinstance(features, list)
        and (pose is None or (isinstance(pose, list) and len(pose) == 3))
    ):
        msg = f"{where}: fields have the wrong types"
        raise ReplayError(msg)
    return RecordedFrame(
        robot=str(robot),
        seq=seq,
        stamp_s=float(stamp),
        features=features,
        pose=None if pose is None else (float(pose[0]), float(pose[1]), float(pose[2])),
    )


@dataclass(slots=True)
class ReplayStats:
    """What a replay sent."""

    frames: int = 0
    robots: int = 0
    elapsed_s: float = 0.0


def replay(
    frames: Iterable[RecordedFrame],
    session: zenoh.Session,
    fleet: str,
    *,
    speed: float | None = 1.0,
    robot_prefix: str = "",
    on_frame: Callable[[int], None] | None = None,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> ReplayStats:
    """Publish frames paced by their stamps; every robot's session is ended at the end.

    Args:
        frames: the frames, in time order (robots interleaved).
        session: an open Zenoh session to the lessmap network.
        fleet: fleet name to publish under; robot names come from the file.
        speed: 1.0 = real time, 10.0 = ten times faster, None = as fast as possible.
        robot_prefix: prepended to the file's robot ids (``"r"`` turns ``"3"`` into ``"r3"``).
        on_frame: called with the running frame count after each frame (progress).
        sleep: waits that many seconds.
        clock: monotonic seconds.
    """
    if speed is not None and speed <= 0:
        msg = f"speed must be positive or None, got {speed}"
        raise ValueError(msg)
    publishers: dict[str, RobotPublisher] = {}
    stats = ReplayStats()
    started = clock()
    first_stamp: float | None = None
    try:
        for frame in frames:
            if first_stamp is None:
                first_stamp = frame.stamp_s
            if speed is not None:
                wait = started + (frame.stamp_s - first_stamp) / speed - clock()
                if wait > 0:
                    sleep(wait)
            publisher = publishers.get(frame.robot)
            if publisher is None:
                name = f"{robot_prefix}{frame.robot}"
                publisher = publishers[frame.robot] = RobotPublisher(fleet, name, session=session)
            publisher.publish(frame.features, stamp_s=frame.stamp_s, pose=frame.pose, seq=frame.seq)
            stats.frames += 1
            if on_frame is not None:
                on_frame(stats.frames)
    finally:
        for publisher in publishers.values():
            publisher.close()
    stats.robots = len(publishers)
    stats.elapsed_s = clock() - started
    return stats

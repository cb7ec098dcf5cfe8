"""Replay a recorded frames file to the service: one publisher per robot in the file.

The reader applies the contract's frames-file rules (``lessmap_schemas.framesfile``, the
same as ``lessmap segment``'s): every malformed line is one ``ReplayError`` ``FILE:LINE:
what``, with the wire limits the service enforces. It also checks what would otherwise only
fail half-way through publishing: robot names and increasing seqs per robot.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lessmap_client.errors import SessionClosedError
from lessmap_client.robot import RobotPublisher
from lessmap_schemas import framesfile
from lessmap_schemas.errors import FramesFileError, InvalidNameError
from lessmap_schemas.keys import validate_name
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator
    from pathlib import Path

    import zenoh

    from lessmap_client.transport import Host
    from lessmap_schemas.messages import SessionState


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


def read_recorded(
    path: Path, limits: WireLimits = DEFAULT_LIMITS, robot_prefix: str = ""
) -> Iterator[RecordedFrame]:
    """Yield the frames of a ``.frames.jsonl`` file in file order; blank lines are skipped.

    Args:
        path: the file.
        limits: the wire limits the service enforces (seq, features per frame, feature ids).
        robot_prefix: prepended to the robot ids, to check the names that will be published.

    Raises:
        ReplayError: a line is not a valid frame (``FILE:LINE: what``).
    """
    last_seq: dict[str, int] = {}
    try:
        for where, line in framesfile.read_lines(path):
            row = framesfile.checked_frame(framesfile.parse_object_line(line, where), where, limits)
            frame = RecordedFrame(
                robot=str(row["robot"]),
                seq=row["seq"],
                stamp_s=float(row["stamp"]),
                features=list(row["features"]),
                pose=framesfile.pose_of(row),
            )
            problem = _sequence_problem(frame, robot_prefix, last_seq, limits)
            if problem is not None:
                msg = f"{where}: {problem}"
                raise ReplayError(msg)
            last_seq[frame.robot] = frame.seq
            yield frame
    except FramesFileError as exc:
        raise ReplayError(str(exc)) from None


def _sequence_problem(
    frame: RecordedFrame, prefix: str, last_seq: dict[str, int], limits: WireLimits
) -> str | None:
    """Checks across lines: a publishable robot name, seqs increasing per robot."""
    if frame.robot not in last_seq:
        try:
            validate_name(f"{prefix}{frame.robot}", "robot", limits)
        except InvalidNameError as exc:
            return str(exc)
        return None
    previous = last_seq[frame.robot]
    if frame.seq <= previous:
        return f"seq {frame.seq} of robot {frame.robot!r} is not above its previous seq {previous}"
    return None


@dataclass(slots=True)
class RobotReplay:
    """What a replay sent for one robot, and what the service reported back."""

    robot: str  # the published name (prefix included)
    session_id: str
    offered: int = 0  # frames published
    skipped: int = 0  # frames of the file not published: the service had closed the session
    closed_by_service: bool = False


@dataclass(slots=True)
class ReplayStats:
    """What a replay sent."""

    frames: int = 0
    robots: int = 0
    elapsed_s: float = 0.0
    per_robot: dict[str, RobotReplay] = field(default_factory=dict)  # by published name


def replay(
    frames: Iterable[RecordedFrame],
    session: zenoh.Session | Host,
    fleet: str,
    *,
    speed: float | None = 1.0,
    robot_prefix: str = "",
    on_frame: Callable[[int], None] | None = None,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
    stats: ReplayStats | None = None,
    wait_service_s: float = 0.0,
) -> ReplayStats:
    """Publish frames paced by their stamps; every robot's session is ended at the end.

    A robot whose session the service closes is not moved to a new session (the file's
    numbering belongs to one session): its remaining frames are skipped and counted.

    Args:
        frames: the frames, in time order (robots interleaved).
        session: an open Zenoh session or ``Connection`` to the lessmap network.
        fleet: fleet name to publish under; robot names come from the file.
        speed: 1.0 = real time, 10.0 = ten times faster, None = as fast as possible.
        robot_prefix: prepended to the file's robot ids (``"r"`` turns ``"3"`` into ``"r3"``).
        on_frame: called with the running frame count after each frame (progress).
        sleep: waits that many seconds.
        clock: monotonic seconds.
        stats: filled as the replay goes (another thread may read it for progress); a new
            one by default. Returned either way.
        wait_service_s: before a robot's first frame, wait up to this long until its
            partition's owner serves it and the owner's subscription reaches the robot
            (``RobotPublisher.wait_for_service``); 0: publish at once.
    """
    if speed is not None and speed <= 0:
        msg = f"speed must be positive or None, got {speed}"
        raise ValueError(msg)
    publishers: dict[str, RobotPublisher] = {}
    stats = ReplayStats() if stats is None else stats
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
                publisher = publishers[frame.robot] = RobotPublisher(
                    fleet, name, session=session, auto_new_session=False
                )
                stats.per_robot[name] = RobotReplay(name, publisher.session_id)
                if wait_service_s > 0:
                    publisher.wait_for_service(wait_service_s)
            record = stats.per_robot[publisher.robot]
            try:
                publisher.publish(
                    frame.features, stamp_s=frame.stamp_s, pose=frame.pose, seq=frame.seq
                )
            except SessionClosedError:
                record.skipped += 1
                continue
            record.offered += 1
            stats.frames += 1
            if on_frame is not None:
                on_frame(stats.frames)
    finally:
        for publisher in publishers.values():
            publisher.flush_errors(0.5)
            stats.per_robot[publisher.robot].closed_by_service = publisher.status.closed_by_service
            publisher.close()
    stats.robots = len(publishers)
    stats.elapsed_s = clock() - started
    return stats


def settled_states(
    states: Callable[[], list[SessionState]],
    stats: ReplayStats,
    *,
    quiet_s: float = 10.0,
    poll_s: float = 0.2,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> dict[str, SessionState]:
    """Wait until the service closed every replayed session; return their final states.

    A session is final once closed: its ``SessionEnd`` came after all its frames on one
    key. Gives up once no state changed for ``quiet_s`` (a robot without a state is then
    missing from the result), so the wait is bounded while the service keeps working
    through a backlog.

    Args:
        states: returns the states of the replay's fleet (e.g. ``conn.states(fleet)``).
        stats: what ``replay`` sent.
        quiet_s: give up after this long without any change.
        poll_s: time between two queries.
        sleep: waits that many seconds.
        clock: monotonic seconds.
    """
    wanted = {(name, record.session_id) for name, record in stats.per_robot.items()}
    found: dict[str, SessionState] = {}
    last_change = clock()
    while True:
        current = {s.robot: s for s in states() if (s.robot, s.session) in wanted}
        if current != found:
            found, last_change = current, clock()
        if len(found) == len(wanted) and not any(s.open for s in found.values()):
            return found
        if clock() - last_change >= quiet_s:
            return found
        sleep(poll_s)


class ProgressReporter:
    """Every ``interval_s``, one line on ``write``: frames sent, acknowledged, rate.

    Acknowledged frames are the service's ``frames_applied`` for the replayed sessions,
    from a state query on the reporter's own thread (so a slow answer never slows the
    replay down).
    """

    def __init__(
        self,
        interval_s: float,
        sent: Callable[[], int],
        acknowledged: Callable[[], int | None],
        write: Callable[[str], None],
        total: int,
    ) -> None:
        self._interval_s = interval_s
        self._sent = sent
        self._acknowledged = acknowledged
        self._write = write
        self._total = total
        self._stop = threading.Event()
        self._started = time.monotonic()
        self._thread = threading.Thread(
            target=self._run, name="lessmap-replay-progress", daemon=True
        )

    def start(self) -> ProgressReporter:
        """Start reporting (no-op for ``interval_s <= 0``)."""
        if self._interval_s > 0:
            self._thread.start()
        return self

    def line(self) -> str:
        """The progress line now."""
        elapsed = time.monotonic() - self._started
        sent = self._sent()
        acknowledged = self._acknowledged()
        ack = "?" if acknowledged is None else str(acknowledged)
        rate = sent / elapsed if elapsed > 0 else 0.0
        return (
            f"{sent}/{self._total} frames sent, {ack} acknowledged, "
            f"{rate:.0f} frames/s, {elapsed:.0f} s"
        )

    def _run(self) -> None:
        while not self._stop.wait(self._interval_s):
            try:
                self._write(self.line())
            except Exception:  # a query on a closing session: progress is best effort
                return

    def stop(self) -> None:
        """Stop reporting (waits for a report being written)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)

"""A robot publisher's bookkeeping: its sessions, the service's reports, the live instances.

Rules of this file:

1. Every field of ``RobotBook`` is read and written under its ``lock``: the publishing thread,
   the follower thread and the transport's thread (live instances) share it.
2. The session id and the numbering change only on the publishing thread (``start_session``):
   a ``SESSION_CLOSED`` report only sets ``closed_report``, which the next ``publish`` acts
   on, so frames are never renumbered behind the caller's back mid-call.
3. Reports are fenced by epoch: an ``Error`` whose epoch is below the highest this robot has
   seen comes from a deposed owner of its partition and is dropped (``stale``).
"""

from __future__ import annotations

import threading
import time
import uuid
from collections import Counter
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING

from lessmap_schemas import partition
from lessmap_schemas.errors import ErrorCode

if TYPE_CHECKING:
    from collections.abc import Mapping

    from lessmap_schemas.messages import Error

__all__ = ["RobotBook", "RobotStatus", "new_session_id"]


def new_session_id() -> str:
    """Return a fresh session id: start time plus randomness, a valid name."""
    return f"{int(time.time())}-{uuid.uuid4().hex[:12]}"


@dataclass(frozen=True, slots=True)
class RobotStatus:
    """What a robot publisher sent and what the service reported back (a snapshot).

    Attributes:
        fleet: fleet of the robot.
        robot: the robot.
        session_id: the current session.
        next_seq: seq the next frame of the current session will carry.
        last_seq: last seq sent in the current session (None before the first frame).
        frames_sent: frames published over every session of this publisher.
        sessions: sessions this publisher started (1, plus one per new session).
        errors: ``Error`` reports about this publisher's sessions, counted per code.
        last_error: the latest of them.
        closed_by_service: the service reported the current session closed; the next
            ``publish`` starts a new session (``auto_new_session``) or raises.
        reports_dropped: reports dropped unread because too many were waiting.
        partition: the robot's partition (``lessmap_schemas.partition.partition_of``), the
            last chunk of its frames key.
        owner: the service instance that owns the partition among the live instances (the
            first by rendezvous ranking), None when no instance is alive: nobody serves the
            robot, and its frames wait in the publisher's cache for the next owner.
        reports_stale: reports dropped because their epoch was below the highest this robot
            had seen (the late report of a deposed owner).
    """

    fleet: str
    robot: str
    session_id: str
    next_seq: int
    last_seq: int | None
    frames_sent: int
    sessions: int
    errors: Mapping[str, int]
    last_error: Error | None
    closed_by_service: bool
    reports_dropped: int = 0
    partition: int = 0
    owner: str | None = None
    reports_stale: int = 0

    def count(self, code: ErrorCode | str) -> int:
        """Reports received with this code (``"SEQ_GAP"`` or ``ErrorCode.SEQ_GAP``)."""
        return self.errors.get(str(code), 0)


class RobotBook:
    """The state a robot publisher's threads share, under one lock (rule 1)."""

    def __init__(self, fleet: str, robot: str, session_id: str) -> None:
        self.fleet = fleet
        self.robot = robot
        self.partition = partition.partition_of(fleet, robot)
        self.lock = threading.Lock()
        self.live_changed = threading.Condition(self.lock)  # notified when ``live`` changes
        self.session_id = session_id
        self.next_seq = 0
        self.frames_sent = 0
        self.sessions = [session_id]
        self.errors: Counter[str] = Counter()
        self.last_error: Error | None = None
        self.closed_report: Error | None = None  # SESSION_CLOSED for the current session
        self.holder: str | None = None  # another open session of this robot name, if seen
        self.closed = False
        self.highest_epoch = 0  # the highest epoch of a report about this robot (rule 3)
        self.stale = 0
        self.live: set[str] = set()  # live service instances
        self.served: str | None = None  # the owner the follower last logged about
        self.unserved_warned = False

    def status(self, reports_dropped: int) -> RobotStatus:
        """Return a snapshot of the book."""
        with self.lock:
            return RobotStatus(
                fleet=self.fleet,
                robot=self.robot,
                session_id=self.session_id,
                next_seq=self.next_seq,
                last_seq=self.last_seq(),
                frames_sent=self.frames_sent,
                sessions=len(self.sessions),
                errors=MappingProxyType(dict(self.errors)),
                last_error=self.last_error,
                closed_by_service=self.closed_report is not None,
                reports_dropped=reports_dropped,
                partition=self.partition,
                owner=self.owner(),
                reports_stale=self.stale,
            )

    def last_seq(self) -> int | None:
        """The last seq sent in the current session (holding ``lock``)."""
        return self.next_seq - 1 if self.next_seq else None

    def owner(self) -> str | None:
        """The owner of the robot's partition among the live instances (holding ``lock``)."""
        return partition.owner_and_standby(self.partition, self.live)[0]

    def start_session(self, session_id: str) -> None:
        """Switch to a new session numbered from 0 (holding ``lock``; rule 2)."""
        self.session_id = session_id
        self.sessions.append(session_id)
        self.next_seq = 0
        self.closed_report = None
        self.holder = None

    def set_live(self, instance: str, *, alive: bool) -> None:
        """Note a service instance's token that appeared or left."""
        with self.lock:
            if alive:
                self.live.add(instance)
            else:
                self.live.discard(instance)
            self.live_changed.notify_all()

    def has_live_instance(self) -> bool:
        """Whether any service instance is alive."""
        with self.lock:
            return bool(self.live)

    def count_report(self, error: Error) -> tuple[bool, str | None]:
        """Count a report; return (counted, the current session if it reports it closed).

        A report about another publisher's session of this robot name, or from a deposed
        owner (rule 3), is not counted.
        """
        with self.lock:
            if error.session is not None and error.session not in self.sessions:
                return False, None
            if error.epoch is not None:
                if error.epoch < self.highest_epoch:
                    self.stale += 1
                    return False, None
                self.highest_epoch = error.epoch
            self.errors[str(error.code)] += 1
            self.last_error = error
            closes_current = (
                error.code == ErrorCode.SESSION_CLOSED
                and error.session == self.session_id
                and self.closed_report is None
            )
            return True, self.session_id if closes_current else None

    def mark_closed(self, session_id: str, error: Error, holder: str | None) -> None:
        """Note that the service closed ``session_id``, if it is still the current one."""
        with self.lock:
            if self.session_id == session_id and self.closed_report is None:
                self.closed_report, self.holder = error, holder

    def note_owner(self, *, startup: bool) -> tuple[str | None, str | None, bool, bool]:
        """Note the current owner; return (owner, the one before, warned before, warn now).

        One warning when the robot becomes unserved (or still is at the end of the start's
        grace), and none again until it is served.
        """
        with self.lock:
            owner = self.owner()
            before, self.served = self.served, owner
            warned = self.unserved_warned
            warn = owner is None and not warned and (before is not None or startup)
            if warn:
                self.unserved_warned = True
            elif owner is not None:
                self.unserved_warned = False
        return owner, before, warned, warn

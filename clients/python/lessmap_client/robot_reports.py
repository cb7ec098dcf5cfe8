"""A robot publisher's follower: the thread that reads the service's reports about the robot.

Rules of this file:

1. The transport's callbacks (Zenoh's thread) only append to the bounded inbox (a raw report,
   or None for a change of the live instances) and update ``RobotBook.live``: constant time,
   no decoding, no log, no Zenoh call.
2. The follower thread takes the inbox in order: it decodes each report, counts it in the
   book, queries the service if needed and calls ``on_error``; on a change of the live
   instances it logs when nobody serves the robot any more, and when somebody does again.
3. Starting a new session would close any other open session of the robot's name, so a
   ``SESSION_CLOSED`` report asks who holds the name first: never fight another publisher.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import TYPE_CHECKING

from lessmap_client.fencing import current_states
from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import Error, SessionState

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap_client.robot_status import RobotBook
    from lessmap_client.transport import Transport

__all__ = ["ReportFollower"]

# The robot side logs under one name, whatever module: users filter on it.
log = logging.getLogger("lessmap_client.robot")

_INBOX_MAX = 1000  # error reports waiting for the follower thread; more are dropped, counted
_HOLDER_QUERY_S = 1.0  # how long the follower asks who holds the robot after SESSION_CLOSED
_JOIN_TIMEOUT_S = 5.0
_UNSERVED_GRACE_S = 2.0  # after this long without an owner since start, warn once


class ReportFollower:
    """The inbox of a robot's reports and the thread that handles them one by one."""

    def __init__(
        self,
        book: RobotBook,
        transport: Transport,
        on_error: Callable[[Error], None] | None,
        new_session_wanted: Callable[[], bool],
    ) -> None:
        self._book = book
        self._transport = transport
        self._on_error = on_error
        self._new_session_wanted = new_session_wanted
        self._inbox: deque[bytes | None] = deque()
        self._inbox_cond = threading.Condition(threading.Lock())
        self._received = 0
        self._handled = 0
        self.dropped = 0
        self._stopping = False
        self.thread = threading.Thread(
            target=self._follow, name=f"lessmap-robot-{book.fleet}/{book.robot}", daemon=True
        )

    def start(self) -> None:
        """Start the follower thread."""
        self.thread.start()

    def push_report(self, payload: bytes) -> None:
        """Queue one raw report (the transport's thread; rule 1)."""
        with self._inbox_cond:
            if self._stopping:
                return
            if len(self._inbox) >= _INBOX_MAX:
                self.dropped += 1
                return
            self._inbox.append(payload)
            self._received += 1
            self._inbox_cond.notify_all()

    def push_instance(self, instance: str, alive: bool) -> None:
        """Note a token that appeared or left (the transport's thread; rule 1)."""
        self._book.set_live(instance, alive=alive)
        with self._inbox_cond:
            if not self._stopping:
                self._inbox.append(None)
                self._received += 1
                self._inbox_cond.notify_all()

    def flush(self, timeout_s: float) -> bool:
        """Wait until every report received so far is handled; False after ``timeout_s``."""
        if threading.current_thread() is self.thread:
            return True  # called from on_error: waiting for ourselves would never end
        with self._inbox_cond:
            target = self._received
            return self._inbox_cond.wait_for(
                lambda: self._handled >= target or self._stopping, timeout_s
            )

    def stop(self) -> None:
        """Drop what waits and end the thread (unless called from it)."""
        with self._inbox_cond:
            self._stopping = True
            self._inbox.clear()
            self._inbox_cond.notify_all()
        if self.thread is not threading.current_thread():
            self.thread.join(_JOIN_TIMEOUT_S)

    def _follow(self) -> None:
        """Handle reports one by one until stopped (rule 2)."""
        grace_until: float | None = time.monotonic() + _UNSERVED_GRACE_S
        while True:
            with self._inbox_cond:
                while not self._inbox and not self._stopping:
                    if grace_until is None:
                        self._inbox_cond.wait()
                        continue
                    remaining = grace_until - time.monotonic()
                    if remaining <= 0:
                        break
                    self._inbox_cond.wait(remaining)
                if self._stopping:
                    return
                popped = bool(self._inbox)
                payload = self._inbox.popleft() if popped else None
                check_startup = grace_until is not None and time.monotonic() >= grace_until
            if check_startup:
                grace_until = None
                self._check_owner(startup=True)
            if not popped:
                continue
            try:
                if payload is None:
                    self._check_owner()
                else:
                    self._handle(payload)
            except Exception:
                log.exception("%s/%s: handling an error report failed", *self._names())
            with self._inbox_cond:
                self._handled += 1
                self._inbox_cond.notify_all()

    def _names(self) -> tuple[str, str]:
        return self._book.fleet, self._book.robot

    def _check_owner(self, *, startup: bool = False) -> None:
        """Log when the robot becomes unserved, and when it is served again."""
        owner, before, warned, warn = self._book.note_owner(startup=startup)
        fleet, robot = self._names()
        part = self._book.partition
        if warn:
            log.warning(
                "%s/%s: no live lessmap instance owns partition %d: the robot is not served "
                "(its recent frames wait in the publisher's cache for the next owner)",
                fleet,
                robot,
                part,
            )
        elif owner is not None and warned:
            log.info("%s/%s: partition %d is served again, by %s", fleet, robot, part, owner)
        elif owner != before and owner is not None:
            log.debug("%s/%s: partition %d owner %s", fleet, robot, part, owner)

    def _handle(self, payload: bytes) -> None:
        fleet, robot = self._names()
        try:
            error = decode(payload, Error)
        except WireError as exc:
            log.warning("%s/%s: skipped an undecodable error report: %s", fleet, robot, exc)
            return
        counted, closes = self._book.count_report(error)
        if not counted:
            return
        log.warning(
            "%s/%s: the service reported %s for session %s seq %s: %s",
            fleet,
            robot,
            error.code,
            error.session,
            error.seq,
            error.detail,
        )
        if closes is not None:
            holder = self._other_holder(closes) if self._new_session_wanted() else None
            self._book.mark_closed(closes, error, holder)
        if self._on_error is not None:
            try:
                self._on_error(error)
            except Exception:
                log.exception("on_error of %s/%s failed", fleet, robot)

    def _other_holder(self, current: str) -> str | None:
        """Return another open session the service holds for this robot name, if any (rule 3)."""
        fleet, robot = self._names()
        try:
            replies = self._transport.get(keys.state(fleet, robot), _HOLDER_QUERY_S)
        except Exception:  # a closed transport: nobody to ask
            return None
        found = []
        for _, payload in replies:
            try:
                found.append(decode(payload, SessionState))
            except WireError:
                continue
        sessions = self._book.sessions
        for state in current_states(found):  # the current owner's answer only
            if state.open and state.session != current and state.session not in sessions:
                return state.session
        return None

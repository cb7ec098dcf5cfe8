"""The robot side: publish frames of one robot session to the lessmap service.

Rules of this file (the bookkeeping's are in ``robot_status``, the follower's in
``robot_reports``):

1. The session id and the numbering change only on the publishing thread (``publish``,
   ``new_session``); the follower thread only flags a session the service closed.
2. The publication cache outlives the ``SessionEnd`` until the service confirms the end
   (``closing.confirm_ends``): it may still need frames from it after a take-over.
3. ``close`` and ``close_all`` never raise and never wait past their timeout.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import zenoh

from lessmap_client.closing import PendingEnd, confirm_ends
from lessmap_client.errors import SessionClosedError
from lessmap_client.fencing import current_states
from lessmap_client.robot_reports import ReportFollower
from lessmap_client.robot_status import RobotBook, RobotStatus, new_session_id
from lessmap_client.session import DEFAULT_ENDPOINT, open_session
from lessmap_client.transport import ZenohTransport
from lessmap_schemas import keys
from lessmap_schemas.codec import decode, encode, encoding
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits
from lessmap_schemas.messages import Error, Frame, Health, SessionEnd, SessionState

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence
    from types import TracebackType

    from lessmap_client.transport import Handle, Host, Transport

__all__ = ["RobotPublisher", "RobotStatus", "SessionClosedError", "close_all", "new_session_id"]

log = logging.getLogger(__name__)

_FRAME_ENCODING = encoding(Frame)
_END_ENCODING = encoding(SessionEnd)
#: How long ``close`` waits for the service to confirm the end: room for a take-over of the
#: robot's partition, whose catch-up from the cache the service bounds by ``catchup_wait_s``
#: (2 s by default).
DEFAULT_CLOSE_TIMEOUT_S = 5.0


class RobotPublisher:
    """Publishes the frames of one robot session, numbered from 0, and follows its errors.

    Declare one with ``conn.robot(fleet, robot)``. Frames go through an ``AdvancedPublisher``
    with a cache, so a service instance that takes the session over can fetch recent frames
    it missed. ``close`` ends the session explicitly (a ``SessionEnd`` with the last seq), so
    the service frees it at once, and keeps the cache until the service confirms the end.

    The publisher follows the service's ``Error`` reports on its own ``errors`` key: each one
    about its sessions is counted in ``status`` and handed to ``on_error`` (on the
    publisher's own thread, never Zenoh's, so the callback may block or query). When the
    service reports the current session closed (``SESSION_CLOSED``), the next ``publish``
    starts a new session (new id, seq from 0) if ``auto_new_session``, else raises
    ``SessionClosedError``. It never takes a robot name over from another publisher: if the
    service holds another open session for the robot, ``publish`` raises either way.

    The robot belongs to one partition (``partition``; its frames key ends with it), served
    by the partition's owner among the live service instances. The publisher follows the
    instances' liveliness tokens: ``status.owner`` is that owner, None when no instance is
    alive. It logs one warning when the robot becomes unserved (or still is 2 s after start)
    and one info line when it is served again; ``wait_for_service`` waits for an owner. An
    unserved robot may keep publishing: the cache keeps its recent frames for the next owner.

    Args:
        fleet: fleet name (letters, digits, ``_ . -``; up to 64 characters).
        robot: robot name, same rule.
        session: the ``Connection`` to publish on, or a Zenoh session to reuse; by default a
            connection is opened to ``connect`` and closed with the publisher.
        connect: endpoints of the lessmap router (used only when ``session`` is None).
        session_id: the session id; a new random one by default (a restarted robot must
            use a new id so the service starts a new CovGraph).
        cache: frames kept for recovery by the service.
        limits: wire limits checked locally before anything is sent.
        on_error: called with every ``Error`` the service reports about this publisher's
            sessions, on the publisher's thread; exceptions in it are logged.
        auto_new_session: start a new session by itself when the service closed the
            current one (default True: a closed session discards every frame, and a robot
            in the field should keep being segmented without an operator; the change shows
            in ``status`` and ``on_error``). False: ``publish`` raises ``SessionClosedError``.
    """

    def __init__(
        self,
        fleet: str,
        robot: str,
        *,
        session: Host | zenoh.Session | None = None,
        connect: Sequence[str] = (DEFAULT_ENDPOINT,),
        session_id: str | None = None,
        cache: int = 1000,
        limits: WireLimits = DEFAULT_LIMITS,
        on_error: Callable[[Error], None] | None = None,
        auto_new_session: bool = True,
    ) -> None:
        self.fleet = keys.validate_name(fleet, "fleet", limits)
        self.robot = keys.validate_name(robot, "robot", limits)
        first_session = keys.validate_name(session_id or new_session_id(), "session", limits)
        self.auto_new_session = auto_new_session
        self._limits = limits
        self._key = keys.frames(self.fleet, self.robot)
        self._book = RobotBook(self.fleet, self.robot, first_session)
        self.partition = self._book.partition
        # A Connection adopts the publisher (closing it ends the session); a Zenoh session or
        # none gets a transport of the publisher's own.
        self._host: Host | None = None
        self._transport: Transport
        if isinstance(session, zenoh.Session):
            self._transport, self._owns_transport = ZenohTransport(session, owned=False), True
        elif session is None:
            opened = open_session(list(connect))
            self._transport, self._owns_transport = ZenohTransport(opened, owned=True), True
        else:
            session._check_open()
            self._host, self._transport, self._owns_transport = session, session.transport, False
        self._publisher = self._transport.publisher(self._key, _FRAME_ENCODING, cache)
        self._follower = ReportFollower(
            self._book, self._transport, on_error, lambda: self.auto_new_session
        )
        self._follower.start()
        self._errors_handle: Handle | None = None
        self._instances_handle: Handle | None = None
        try:
            self._errors_handle = self._transport.subscribe(
                keys.errors(self.fleet, self.robot), self._follower.push_report, history=None
            )
            self._instances_handle = self._transport.watch_instances(self._follower.push_instance)
        except BaseException:
            self._release_handles()
            self._follower.stop()
            self._publisher.close()
            if self._owns_transport:
                self._transport.close()
            raise
        if self._host is not None:
            self._host._adopt(self)

    @property
    def session_id(self) -> str:
        """The current session."""
        return self._book.session_id

    @property
    def next_seq(self) -> int:
        """Seq the next frame will carry."""
        return self._book.next_seq

    @property
    def closed(self) -> bool:
        """Whether the session was ended."""
        return self._book.closed

    @property
    def status(self) -> RobotStatus:
        """A snapshot of what was sent and what the service reported about it."""
        return self._book.status(self._follower.dropped)

    def wait_for_service(self, timeout_s: float = 10.0) -> bool:
        """Wait until the robot's partition has an owner that serves it; False after ``timeout_s``.

        The owner is the first of the live instances by rendezvous ranking (``status.owner``);
        any live instance owns some partitions, and with one alive every partition has an
        owner. A new owner takes its partitions a moment after its token appears, so this
        also asks the owner's ``Health`` and waits until it lists the partition (an owner
        that does not answer Health queries is taken at its token). Frames published before
        that are not lost while the robot keeps publishing: the publisher's cache keeps
        them for the owner to fetch. Last, it waits until the owner's frames subscription
        matches this robot's key, so the next frame is routed to the owner.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            with self._book.live_changed:
                while (owner := self._book.owner()) is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return False
                    self._book.live_changed.wait(remaining)
            if self._owner_serves(owner, min(1.0, max(0.1, deadline - time.monotonic()))):
                # Served, and the owner's frames subscription has reached this session: a
                # frame published now is routed to it (before that, Zenoh would drop it here).
                while not self._publisher.matched():
                    if time.monotonic() >= deadline:
                        return False
                    time.sleep(0.02)
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.05)

    def _owner_serves(self, owner: str, timeout_s: float) -> bool:
        """Whether ``owner`` lists the robot's partition in its Health (True if it is silent)."""
        try:
            replies = self._transport.get(keys.health(owner), timeout_s)
        except Exception:  # a closed transport: nobody to ask
            return False
        answered = False
        for _, payload in replies:
            try:
                health = decode(payload, Health)
            except WireError:
                continue
            answered = True
            if health.instance == owner and self._book.partition in health.partitions:
                return True
        return not answered

    def state(self, timeout_s: float = 2.0) -> SessionState | None:
        """Ask the service for the state of the current session (blocks up to ``timeout_s``).

        Returns None when no instance answers for this session (no frame of it arrived
        yet, no service, or the service holds another session for this robot name). Call it
        from your thread or ``on_error``, never from a Zenoh callback.
        """
        session_id = self.session_id
        found = []
        for reply_key, payload in self._transport.get(
            keys.state(self.fleet, self.robot), timeout_s
        ):
            try:
                found.append(decode(payload, SessionState))
            except WireError as exc:
                log.warning("skipped an undecodable reply on %s: %s", reply_key, exc)
        # Of several replies (an old and a new owner), the highest epoch is current.
        current = current_states(found)
        if current and current[0].session == session_id:
            return current[0]
        return None

    def publish(
        self,
        features: Iterable[int],
        *,
        stamp_s: float | None = None,
        pose: tuple[float, float, float] | None = None,
        seq: int | None = None,
    ) -> int:
        """Publish one frame and return its seq (call it from one thread at a time).

        Args:
            features: IDs of the features seen together (non-negative ints < 2**63).
            stamp_s: time of the frame in seconds (default: now).
            pose: optional (x_m, y_m, theta_rad).
            seq: explicit seq (must be >= the next one; a gap is reported by the service).
                After a new session the numbering starts again at 0 (``next_seq``).

        Raises:
            WireError: the frame breaks a limit or a type rule (nothing was sent).
            SessionClosedError: the service closed the session and no new one is started
                (``auto_new_session=False``, or another publisher holds the robot name).
            RuntimeError: the publisher is closed.
        """
        book = self._book
        with book.lock:
            if book.closed:
                msg = "RobotPublisher is closed"
                raise RuntimeError(msg)
            if book.closed_report is not None:
                if not self.auto_new_session or book.holder is not None:
                    raise SessionClosedError(
                        self.fleet, self.robot, book.session_id, book.closed_report, book.holder
                    )
                old = book.session_id
                book.start_session(new_session_id())
                log.warning(
                    "%s/%s: the service closed session %s; publishing under new session %s",
                    self.fleet,
                    self.robot,
                    old,
                    book.session_id,
                )
            session_id, next_seq = book.session_id, book.next_seq
        feature_list = list(features)
        if len(feature_list) > self._limits.max_features_per_frame:
            msg = (
                f"frame has {len(feature_list)} features, over max_features_per_frame="
                f"{self._limits.max_features_per_frame}"
            )
            raise WireError(msg, code=ErrorCode.LIMIT_EXCEEDED, limit="max_features_per_frame")
        frame_seq = next_seq if seq is None else seq
        if frame_seq < next_seq:
            msg = f"seq {frame_seq} is before the next seq {next_seq}"
            raise WireError(msg, code=ErrorCode.OUT_OF_ORDER)
        try:
            frame = Frame(
                session=session_id,
                seq=frame_seq,
                stamp_s=time.time() if stamp_s is None else stamp_s,
                features=feature_list,
                pose=pose,
            )
        except ValueError as exc:
            msg = f"not a valid frame: {exc}"
            raise WireError(msg, code=ErrorCode.INVALID) from exc
        payload = encode(frame)
        if len(payload) > self._limits.max_payload_bytes:
            msg = f"frame of {len(payload)} bytes, over max_payload_bytes"
            raise WireError(msg, code=ErrorCode.LIMIT_EXCEEDED, limit="max_payload_bytes")
        self._publisher.put(payload)
        with book.lock:
            book.frames_sent += 1
            if book.session_id == session_id:
                book.next_seq = frame_seq + 1
        return frame_seq

    def new_session(self, session_id: str | None = None) -> str:
        """End the current session (unless the service closed it) and start a new one.

        The next frame carries seq 0 under the new id (a fresh random one by default).
        Returns the new session id.
        """
        new_id = keys.validate_name(session_id or new_session_id(), "session", self._limits)
        book = self._book
        with book.lock:
            if book.closed:
                msg = "RobotPublisher is closed"
                raise RuntimeError(msg)
            if new_id in book.sessions:
                msg = f"session id {new_id!r} was already used by this publisher"
                raise ValueError(msg)
            old, still_open = book.session_id, book.closed_report is None
            last = book.last_seq()
            book.start_session(new_id)
        if still_open:
            self._send_end(old, last)
        return new_id

    def flush_errors(self, timeout_s: float = 1.0) -> bool:
        """Wait until every error report received so far is handled (status, ``on_error``).

        Reports still on the network are not waited for. With the in-process ``FakeBus``,
        whose delivery is synchronous, a report injected before this call is reflected in
        ``status`` when it returns True. False after ``timeout_s``.
        """
        return self._follower.flush(timeout_s)

    # -- lifetime --------------------------------------------------------------------------

    def _send_end(self, session_id: str, last_seq: int | None) -> bool:
        end = SessionEnd(session=session_id, last_seq=last_seq, stamp_s=time.time())
        try:
            # Same key as the frames: Zenoh keeps the order of puts on one key.
            self._transport.put(self._key, encode(end), _END_ENCODING)
        except Exception:  # zenoh.ZError, or a transport already closed
            log.warning("could not send the end of session %s", session_id)
            return False
        return True

    def _release_handles(self) -> None:
        for name in ("_errors_handle", "_instances_handle"):
            handle = getattr(self, name)
            setattr(self, name, None)
            if handle is not None:
                handle.close()

    def close(self, timeout_s: float = DEFAULT_CLOSE_TIMEOUT_S) -> None:
        """End the session, wait until the service confirms the end, then release (idempotent).

        The ``SessionEnd`` (with the last seq) goes out first. The publication cache then
        stays until the service's ``SessionState`` shows the session closed, or every frame
        up to the last seq applied: if the robot's partition moves between instances at
        that moment, the frames queued at the old owner are lost there and the new owner
        fetches them from this cache. Polls the robot's ``state`` key every 20-250 ms.

        Never raises and never hangs: after ``timeout_s``, or at once when no service
        instance is alive or the network is closed, it logs one warning and closes anyway.
        ``timeout_s=0`` closes right after sending the end. Closing many robots: use
        ``close_all``, which waits for them together.
        """
        close_all([self], timeout_s)

    def _end_for_close(self, *, confirm: bool) -> tuple[bool, PendingEnd | None]:
        """Mark closed and send the end; return (closed by this call, the end to confirm)."""
        book = self._book
        with book.lock:
            if book.closed:
                return False, None
            book.closed = True
            still_open = book.closed_report is None
            last = book.last_seq()
            session_id = book.session_id
        if not still_open or not self._send_end(session_id, last):
            return True, None
        # Only a Zenoh publisher has a cache a service can query: the in-process fake
        # (lessmap_client.testing) has no service behind it to confirm anything.
        if not confirm or last is None or not isinstance(self._transport, ZenohTransport):
            return True, None
        return True, PendingEnd(
            fleet=self.fleet,
            robot=self.robot,
            session=session_id,
            last_seq=last,
            transport=self._transport,
            route=self._transport.session,
            served=book.has_live_instance,
            closed_by_service=lambda: book.closed_report is not None,
            resend=lambda: self._send_end(session_id, last),
        )

    def _release_after_close(self) -> None:
        self._release_handles()
        self._follower.stop()
        self._publisher.close()
        if self._host is not None:
            self._host._release(self)
        if self._owns_transport:
            self._transport.close()

    def __enter__(self) -> RobotPublisher:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def close_all(
    publishers: Iterable[RobotPublisher], timeout_s: float = DEFAULT_CLOSE_TIMEOUT_S
) -> None:
    """Close many robot publishers together: every end first, then one wait for them all.

    ``RobotPublisher.close`` one after the other costs one confirmation latency per robot;
    this sends every ``SessionEnd``, then polls the states of all the robots at once (one
    query per Zenoh session and fleet, with a wildcard key when several robots of a fleet
    wait), then releases every publisher. The rules of ``close`` apply: never raises, at
    most ``timeout_s`` of waiting, one warning line for the ends left unconfirmed.
    Publishers already closed are skipped.
    """
    closing = []
    ends = []
    for publisher in publishers:
        closed_here, end = publisher._end_for_close(confirm=timeout_s > 0)
        if closed_here:
            closing.append(publisher)
        if end is not None:
            ends.append(end)
    try:
        for left in confirm_ends(ends, timeout_s) if ends else []:
            names = ", ".join(f"{e.fleet}/{e.robot}" for e in left.ends[:5])
            more = f" and {len(left.ends) - 5} more" if len(left.ends) > 5 else ""
            log.warning(
                "end of %d session(s) not confirmed by the service (%s): %s%s; closing their "
                "publication caches anyway, frames not applied yet are lost",
                len(left.ends),
                left.reason,
                names,
                more,
            )
    except Exception:  # never raise from a close: the publishers are released below
        log.exception("confirming the session ends failed")
    for publisher in closing:
        try:
            publisher._release_after_close()
        except Exception:  # one publisher's failure must not keep the others' threads alive
            log.exception("releasing %s/%s failed", publisher.fleet, publisher.robot)

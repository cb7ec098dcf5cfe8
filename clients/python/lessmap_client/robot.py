"""The robot side: publish frames of one robot session to the lessmap service.

Invariants of this file:

- A robot follows its own ``errors`` key. The transport's callback (Zenoh's thread) only
  appends the raw payload to the robot's bounded inbox; the robot's follower thread decodes
  it, updates the status, queries the service if needed and calls ``on_error``.
- A robot follows the service instances' liveliness tokens: the transport's callback only
  updates the set of live instances (and wakes the follower); ``status.owner`` ranks that set
  for the robot's partition (contract section 2a), and the follower logs when nobody serves
  the robot any more, and when somebody does again.
- Reports are fenced by epoch: an ``Error`` whose epoch is below the highest this robot has
  seen comes from a deposed owner of its partition and is dropped (``reports_stale``).
- The session id and the numbering change only on the publishing thread (``publish``,
  ``new_session``): a ``SESSION_CLOSED`` report is turned into a flag that the next
  ``publish`` acts on, so frames are never renumbered behind the caller's back mid-call.
- The publication cache outlives the ``SessionEnd`` until the service confirms the end
  (``closing.confirm_ends``): it may still need frames from it after a take-over.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections import Counter, deque
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING

import zenoh

from lessmap_client.closing import PendingEnd, confirm_ends
from lessmap_client.errors import SessionClosedError
from lessmap_client.fencing import current_states
from lessmap_client.session import DEFAULT_ENDPOINT, open_session
from lessmap_client.transport import ZenohTransport
from lessmap_schemas import keys, partition
from lessmap_schemas.codec import decode, encode, encoding
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits
from lessmap_schemas.messages import Error, Frame, Health, SessionEnd, SessionState

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence
    from types import TracebackType

    from lessmap_client.transport import Handle, Host, Transport

__all__ = ["RobotPublisher", "RobotStatus", "SessionClosedError", "close_all", "new_session_id"]

log = logging.getLogger(__name__)

_FRAME_ENCODING = encoding(Frame)
_END_ENCODING = encoding(SessionEnd)
_INBOX_MAX = 1000  # error reports waiting for the follower thread; more are dropped, counted
_HOLDER_QUERY_S = 1.0  # how long the follower asks who holds the robot after SESSION_CLOSED
_JOIN_TIMEOUT_S = 5.0
_UNSERVED_GRACE_S = 2.0  # after this long without an owner since start, warn once
#: How long ``close`` waits for the service to confirm the end: room for a take-over of the
#: robot's partition, whose catch-up from the cache the service bounds by ``catchup_wait_s``
#: (2 s by default).
DEFAULT_CLOSE_TIMEOUT_S = 5.0


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
        self.session_id = keys.validate_name(session_id or new_session_id(), "session", limits)
        self.auto_new_session = auto_new_session
        self._limits = limits
        self._on_error = on_error
        self._key = keys.frames(self.fleet, self.robot)
        self.partition = partition.partition_of(self.fleet, self.robot)
        # Session bookkeeping (the publishing thread and the follower share it).
        self._lock = threading.Lock()
        self._next_seq = 0
        self._frames_sent = 0
        self._sessions = [self.session_id]
        self._errors: Counter[str] = Counter()
        self._last_error: Error | None = None
        self._closed_report: Error | None = None  # SESSION_CLOSED for the current session
        self._holder: str | None = None  # another open session of this robot name, if seen
        self._closed = False
        self._highest_epoch = 0  # fencing: the highest epoch of a report about this robot
        self._stale = 0
        # Live service instances (the transport's thread updates them under ``_lock``).
        self._live: set[str] = set()
        self._live_changed = threading.Condition(self._lock)
        self._served: str | None = None  # the owner the follower last logged about
        self._unserved_warned = False
        # The inbox of raw error reports (Zenoh's thread appends, the follower takes); None
        # marks a change of the live instances.
        self._inbox: deque[bytes | None] = deque()
        self._inbox_cond = threading.Condition(threading.Lock())
        self._received = 0
        self._handled = 0
        self._dropped = 0
        self._stopping = False
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
        self._follower = threading.Thread(
            target=self._follow, name=f"lessmap-robot-{self.fleet}/{self.robot}", daemon=True
        )
        self._follower.start()
        self._errors_handle: Handle | None = None
        self._instances_handle: Handle | None = None
        try:
            self._errors_handle = self._transport.subscribe(
                keys.errors(self.fleet, self.robot), self._push_error, history=None
            )
            self._instances_handle = self._transport.watch_instances(self._on_instance)
        except BaseException:
            self._release_handles()
            self._stop_follower()
            self._publisher.close()
            if self._owns_transport:
                self._transport.close()
            raise
        if self._host is not None:
            self._host._adopt(self)

    @property
    def next_seq(self) -> int:
        """Seq the next frame will carry."""
        return self._next_seq

    @property
    def closed(self) -> bool:
        """Whether the session was ended."""
        return self._closed

    @property
    def status(self) -> RobotStatus:
        """A snapshot of what was sent and what the service reported about it."""
        with self._lock:
            return RobotStatus(
                fleet=self.fleet,
                robot=self.robot,
                session_id=self.session_id,
                next_seq=self._next_seq,
                last_seq=self._next_seq - 1 if self._next_seq else None,
                frames_sent=self._frames_sent,
                sessions=len(self._sessions),
                errors=MappingProxyType(dict(self._errors)),
                last_error=self._last_error,
                closed_by_service=self._closed_report is not None,
                reports_dropped=self._dropped,
                partition=self.partition,
                owner=self._owner(),
                reports_stale=self._stale,
            )

    def _owner(self) -> str | None:
        """The owner of the robot's partition among the live instances (holding ``_lock``)."""
        return partition.owner_and_standby(self.partition, self._live)[0]

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
            with self._live_changed:
                while (owner := self._owner()) is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return False
                    self._live_changed.wait(remaining)
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
            if health.instance == owner and self.partition in health.partitions:
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
        with self._lock:
            if self._closed:
                msg = "RobotPublisher is closed"
                raise RuntimeError(msg)
            if self._closed_report is not None:
                if not self.auto_new_session or self._holder is not None:
                    raise SessionClosedError(
                        self.fleet, self.robot, self.session_id, self._closed_report, self._holder
                    )
                old = self.session_id
                self._start_session(new_session_id())
                log.warning(
                    "%s/%s: the service closed session %s; publishing under new session %s",
                    self.fleet,
                    self.robot,
                    old,
                    self.session_id,
                )
            session_id, next_seq = self.session_id, self._next_seq
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
        with self._lock:
            self._frames_sent += 1
            if self.session_id == session_id:
                self._next_seq = frame_seq + 1
        return frame_seq

    def new_session(self, session_id: str | None = None) -> str:
        """End the current session (unless the service closed it) and start a new one.

        The next frame carries seq 0 under the new id (a fresh random one by default).
        Returns the new session id.
        """
        new_id = keys.validate_name(session_id or new_session_id(), "session", self._limits)
        with self._lock:
            if self._closed:
                msg = "RobotPublisher is closed"
                raise RuntimeError(msg)
            if new_id in self._sessions:
                msg = f"session id {new_id!r} was already used by this publisher"
                raise ValueError(msg)
            old, still_open = self.session_id, self._closed_report is None
            last = self._next_seq - 1 if self._next_seq else None
            self._start_session(new_id)
        if still_open:
            self._send_end(old, last)
        return new_id

    def _start_session(self, session_id: str) -> None:
        """Switch to a new session numbered from 0 (holding ``_lock``)."""
        self.session_id = session_id
        self._sessions.append(session_id)
        self._next_seq = 0
        self._closed_report = None
        self._holder = None

    def flush_errors(self, timeout_s: float = 1.0) -> bool:
        """Wait until every error report received so far is handled (status, ``on_error``).

        Reports still on the network are not waited for. With the in-process ``FakeBus``,
        whose delivery is synchronous, a report injected before this call is reflected in
        ``status`` when it returns True. False after ``timeout_s``.
        """
        if threading.current_thread() is self._follower:
            return True  # called from on_error: waiting for ourselves would never end
        with self._inbox_cond:
            target = self._received
            return self._inbox_cond.wait_for(
                lambda: self._handled >= target or self._stopping, timeout_s
            )

    # -- the service's instances ------------------------------------------------------------

    def _on_instance(self, instance: str, alive: bool) -> None:
        """Note a token that appeared or left (the transport's thread: no log, no Zenoh)."""
        with self._lock:
            if alive:
                self._live.add(instance)
            else:
                self._live.discard(instance)
            self._live_changed.notify_all()
        with self._inbox_cond:
            if not self._stopping:
                self._inbox.append(None)
                self._received += 1
                self._inbox_cond.notify_all()

    def _check_owner(self, *, startup: bool = False) -> None:
        """Log when the robot becomes unserved, and when it is served again (follower)."""
        with self._lock:
            owner = self._owner()
            before, self._served = self._served, owner
            warned = self._unserved_warned
            if owner is None and not warned and (before is not None or startup):
                self._unserved_warned = True
            elif owner is not None:
                self._unserved_warned = False
        if owner is None and not warned and (before is not None or startup):
            log.warning(
                "%s/%s: no live lessmap instance owns partition %d: the robot is not served "
                "(its recent frames wait in the publisher's cache for the next owner)",
                self.fleet,
                self.robot,
                self.partition,
            )
        elif owner is not None and warned:
            log.info(
                "%s/%s: partition %d is served again, by %s",
                self.fleet,
                self.robot,
                self.partition,
                owner,
            )
        elif owner != before and owner is not None:
            log.debug("%s/%s: partition %d owner %s", self.fleet, self.robot, self.partition, owner)

    # -- the service's reports -------------------------------------------------------------

    def _push_error(self, payload: bytes) -> None:
        """Queue one raw report (the transport's thread: constant time, no Zenoh, no log)."""
        with self._inbox_cond:
            if self._stopping:
                return
            if len(self._inbox) >= _INBOX_MAX:
                self._dropped += 1
                return
            self._inbox.append(payload)
            self._received += 1
            self._inbox_cond.notify_all()

    def _follow(self) -> None:
        """The follower thread: handle reports one by one until the publisher closes."""
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
                log.exception("%s/%s: handling an error report failed", self.fleet, self.robot)
            with self._inbox_cond:
                self._handled += 1
                self._inbox_cond.notify_all()

    def _handle(self, payload: bytes) -> None:
        try:
            error = decode(payload, Error)
        except WireError as exc:
            log.warning(
                "%s/%s: skipped an undecodable error report: %s", self.fleet, self.robot, exc
            )
            return
        with self._lock:
            if error.session is not None and error.session not in self._sessions:
                return  # about another publisher's session of this robot name
            if error.epoch is not None:
                if error.epoch < self._highest_epoch:
                    self._stale += 1  # a deposed owner's late report
                    return
                self._highest_epoch = error.epoch
            self._errors[str(error.code)] += 1
            self._last_error = error
            current = self.session_id
            closes_current = (
                error.code == ErrorCode.SESSION_CLOSED
                and error.session == current
                and self._closed_report is None
            )
        log.warning(
            "%s/%s: the service reported %s for session %s seq %s: %s",
            self.fleet,
            self.robot,
            error.code,
            error.session,
            error.seq,
            error.detail,
        )
        if closes_current:
            # Starting a new session would close any other open session of this robot name:
            # never fight another publisher for it.
            holder = self._other_holder(current) if self.auto_new_session else None
            with self._lock:
                if self.session_id == current and self._closed_report is None:
                    self._closed_report, self._holder = error, holder
        if self._on_error is not None:
            try:
                self._on_error(error)
            except Exception:
                log.exception("on_error of %s/%s failed", self.fleet, self.robot)

    def _other_holder(self, current: str) -> str | None:
        """Return another open session the service holds for this robot name, if any."""
        try:
            replies = self._transport.get(keys.state(self.fleet, self.robot), _HOLDER_QUERY_S)
        except Exception:  # a closed transport: nobody to ask
            return None
        found = []
        for _, payload in replies:
            try:
                found.append(decode(payload, SessionState))
            except WireError:
                continue
        for state in current_states(found):  # the current owner's answer only
            if state.open and state.session != current and state.session not in self._sessions:
                return state.session
        return None

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

    def _stop_follower(self) -> None:
        with self._inbox_cond:
            self._stopping = True
            self._inbox.clear()
            self._inbox_cond.notify_all()
        if self._follower is not threading.current_thread():
            self._follower.join(_JOIN_TIMEOUT_S)

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
        with self._lock:
            if self._closed:
                return False, None
            self._closed = True
            still_open = self._closed_report is None
            last = self._next_seq - 1 if self._next_seq else None
            session_id = self.session_id
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
            served=self._has_live_instance,
            closed_by_service=lambda: self._closed_report is not None,
            resend=lambda: self._send_end(session_id, last),
        )

    def _has_live_instance(self) -> bool:
        with self._lock:
            return bool(self._live)

    def _release_after_close(self) -> None:
        self._release_handles()
        self._stop_follower()
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

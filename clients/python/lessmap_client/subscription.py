"""One subscription: its own bounded queue, or its own handler thread.

Rules of this file:

1. Every ``Subscription`` owns its queue: two subscriptions on one key each get every event.
2. ``_push`` runs on the transport's thread (Zenoh's): it appends raw bytes under a lock held
   for a few instructions and returns. It never decodes, logs, blocks or calls Zenoh.
3. Overflow: when ``maxsize`` events wait unread, a new event is dropped and counted in
   ``dropped``, so a slow reader gets an unbroken prefix (as nats.py's pending limits); the
   reader's side logs a warning when it notices new drops.
4. Decoding, fencing and de-duplication happen on the reader's thread (``recv``) or on the
   subscription's own dispatcher thread (handler mode).
5. Fencing (contract section 2a): per robot, an event with an ``epoch`` below the highest
   seen (a deposed owner's late event) is dropped and counted in ``dropped_stale``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict, deque
from typing import TYPE_CHECKING, Generic, TypeVar

from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import Error, Transition

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from types import TracebackType

    from lessmap_client.transport import Handle

log = logging.getLogger(__name__)

T = TypeVar("T")

#: Events a subscription buffers by default before it drops new ones.
DEFAULT_MAXSIZE = 10_000
_SEEN_KEPT = 100_000  # transition identities remembered for de-duplication
_EPOCHS_KEPT = 100_000  # robots whose highest epoch is remembered for fencing
_JOIN_TIMEOUT_S = 5.0


class Subscription(Generic[T]):
    """Events of one declaration, read by iteration, ``recv``/``try_recv`` or a handler.

    Made by ``Connection.subscribe_transitions`` and its siblings, never directly.

    With ``handler``, a thread of this subscription calls it with every event, outside
    Zenoh's threads, so it may block or call the connection's queries; an exception in it is
    logged and the next event still arrives. Without one, the caller reads the queue.

    Events are fenced by epoch: per robot ``(fleet, robot)``, the subscription keeps the
    highest ``epoch`` it has seen on a ``Transition`` or an ``Error`` (an ``Error`` whose
    epoch is null is never fenced) and drops an event with a lower one, the late event of an
    instance that no longer owns the robot's partition; ``dropped_stale`` counts them.

    Transitions are then de-duplicated by identity
    ``(fleet, robot, session, incarnation, closed.id)``: the
    history recovered on joining and the live stream may overlap, and a new owner of a
    partition computes the transitions after its checkpoint again; ``duplicates`` counts them.
    """

    def __init__(
        self,
        decoder: Callable[[bytes], T],
        *,
        name: str,
        maxsize: int = DEFAULT_MAXSIZE,
        handler: Callable[[T], None] | None = None,
        on_close: Callable[[Subscription[T]], None] | None = None,
    ) -> None:
        if maxsize < 1:
            msg = f"maxsize must be at least 1, got {maxsize}"
            raise ValueError(msg)
        self.name = name
        self.maxsize = maxsize
        self._decoder = decoder
        self._handler = handler
        self._on_close = on_close
        self._cond = threading.Condition(threading.Lock())
        self._queue: deque[bytes] = deque()
        self._dropped = 0
        self._dropped_logged = 0
        self._closed = False
        self.undecodable = 0  # payloads that were not valid messages (logged, skipped)
        self.duplicates = 0  # transitions skipped as repeats
        self.dropped_stale = 0  # events skipped for an epoch below the robot's highest
        self._seen: OrderedDict[tuple[str, str, str, int, int], None] = OrderedDict()
        self._epochs: OrderedDict[tuple[str, str], int] = OrderedDict()
        self._handles: list[Handle] = []
        self._dispatcher: threading.Thread | None = None
        if handler is not None:
            self._dispatcher = threading.Thread(
                target=self._dispatch, name=f"lessmap-sub-{name}", daemon=True
            )
            self._dispatcher.start()

    # -- the transport's side ----------------------------------------------------------------

    def _attach(self, handle: Handle) -> None:
        """Own a transport declaration feeding this subscription (released by ``close``)."""
        with self._cond:
            closed = self._closed
            if not closed:
                self._handles.append(handle)
        if closed:
            handle.close()

    def _push(self, payload: bytes) -> None:
        """Queue one raw payload (transport thread: constant time, never blocks for long)."""
        with self._cond:
            if self._closed:
                return
            if len(self._queue) >= self.maxsize:
                self._dropped += 1
                return
            self._queue.append(payload)
            self._cond.notify()

    # -- the reader's side -------------------------------------------------------------------

    @property
    def dropped(self) -> int:
        """Events dropped because ``maxsize`` events were waiting unread."""
        return self._dropped

    @property
    def pending(self) -> int:
        """Events received and not read yet (repeats not removed yet)."""
        return len(self._queue)

    @property
    def closed(self) -> bool:
        """Whether ``close`` was called."""
        return self._closed

    def recv(self, timeout_s: float | None = None) -> T | None:
        """Return the next event; None after ``timeout_s``, or once closed and drained.

        Raises:
            RuntimeError: the subscription has a handler (the handler gets the events).
        """
        self._check_reader()
        return self._take(timeout_s)

    def try_recv(self) -> T | None:
        """Return the next event if one is waiting, else None (never blocks)."""
        self._check_reader()
        return self._take(0.0)

    def __iter__(self) -> Iterator[T]:
        """Yield events until the subscription is closed and drained."""
        self._check_reader()
        while (event := self._take(None)) is not None:
            yield event

    def _check_reader(self) -> None:
        if self._handler is not None:
            msg = f"subscription {self.name} delivers to its handler; it cannot be read"
            raise RuntimeError(msg)

    def _take(self, timeout_s: float | None) -> T | None:
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            with self._cond:
                while not self._queue:
                    if self._closed:
                        return None
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        return None
                    self._cond.wait(remaining)
                payload = self._queue.popleft()
                dropped = self._dropped
            if dropped > self._dropped_logged:
                log.warning(
                    "subscription %s dropped %d events: its queue was full (maxsize %d)",
                    self.name,
                    dropped - self._dropped_logged,
                    self.maxsize,
                )
                self._dropped_logged = dropped
            event = self._decode(payload)
            if event is not None:
                return event

    def _decode(self, payload: bytes) -> T | None:
        try:
            event = self._decoder(payload)
        except WireError as exc:
            self.undecodable += 1
            log.warning("subscription %s skipped an undecodable event: %s", self.name, exc)
            return None
        if isinstance(event, Transition | Error) and self._is_stale(event):
            self.dropped_stale += 1
            log.debug("subscription %s dropped a stale event (epoch %s)", self.name, event.epoch)
            return None
        if isinstance(event, Transition) and self._is_repeat(event):
            self.duplicates += 1
            return None
        return event

    def _is_stale(self, event: Transition | Error) -> bool:
        """Whether the event's epoch is below the highest seen for its robot (then keep it)."""
        if event.epoch is None or event.fleet is None or event.robot is None:
            return False
        robot = (event.fleet, event.robot)
        highest = self._epochs.get(robot)
        if highest is not None and event.epoch < highest:
            return True
        self._epochs[robot] = event.epoch
        self._epochs.move_to_end(robot)
        if len(self._epochs) > _EPOCHS_KEPT:
            self._epochs.popitem(last=False)
        return False

    def _is_repeat(self, t: Transition) -> bool:
        identity = (t.fleet, t.robot, t.session, t.incarnation, t.closed.id)
        if identity in self._seen:
            return True
        self._seen[identity] = None
        if len(self._seen) > _SEEN_KEPT:
            self._seen.popitem(last=False)
        return False

    def _dispatch(self) -> None:
        assert self._handler is not None
        while (event := self._take(None)) is not None:
            if self._closed:
                return  # close() discards what the handler has not been given yet
            try:
                self._handler(event)
            except Exception:
                log.exception("handler of subscription %s failed", self.name)

    # -- lifetime ----------------------------------------------------------------------------

    def close(self) -> None:
        """Stop receiving (idempotent, never hangs).

        Reading: events already queued can still be read, then iteration ends and ``recv``
        returns None. Handler mode: events not yet handed to the handler are discarded, and
        ``close`` waits (up to 5 s) for a running handler call to return, unless it is called
        from the handler itself.
        """
        with self._cond:
            if self._closed:
                return
            self._closed = True
            handles, self._handles = self._handles, []
            if self._handler is not None:
                self._queue.clear()
            self._cond.notify_all()
        for handle in handles:
            handle.close()
        dispatcher = self._dispatcher
        if dispatcher is not None and dispatcher is not threading.current_thread():
            dispatcher.join(_JOIN_TIMEOUT_S)
        if self._on_close is not None:
            self._on_close(self)

    def __enter__(self) -> Subscription[T]:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<Subscription {self.name} {state} pending={self.pending} dropped={self.dropped}>"

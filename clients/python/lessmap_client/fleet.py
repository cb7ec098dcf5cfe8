"""The fleet side: receive transitions of one robot, a fleet or everything; query state.

Zenoh delivers samples on its own threads; the callback here only appends the raw bytes to
a queue (Zenoh must not be blocked or re-entered from a callback), and decoding happens in
the caller's thread when it takes an event.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import OrderedDict
from typing import TYPE_CHECKING, TypeVar

import zenoh
from zenoh import ext

from lessmap_client.session import DEFAULT_ENDPOINT, open_session, service_instances
from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import Error, Health, SessionState, Submap, Transition

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence
    from types import TracebackType

log = logging.getLogger(__name__)

_CLOSED = object()
_SEEN_KEPT = 100_000
M = TypeVar("M", SessionState, Submap, Health)


class FleetClient:
    """Typed events and queries for a fleet app.

    Args:
        fleet: fleet name, or ``"*"`` for every fleet.
        robot: robot name, or ``"*"`` for every robot of the fleet(s).
        session: a Zenoh session to reuse; by default one is opened to ``connect``.
        connect: endpoints of the lessmap router (used only when ``session`` is None).
        history: recent transitions per robot to recover on joining (0: live only).
        errors: also receive the service's ``Error`` events for these robots.
    """

    def __init__(
        self,
        fleet: str = "*",
        robot: str = "*",
        *,
        session: zenoh.Session | None = None,
        connect: Sequence[str] = (DEFAULT_ENDPOINT,),
        history: int = 64,
        errors: bool = False,
    ) -> None:
        self.fleet = fleet
        self.robot = robot
        self._owns_session = session is None
        self._session = session if session is not None else open_session(connect)
        self._events: queue.SimpleQueue[tuple[str, bytes] | object] = queue.SimpleQueue()
        self.undecodable = 0  # samples that were not valid messages (logged, skipped)
        # Transition identities already delivered: (fleet, robot, session, closed submap id).
        self._seen: OrderedDict[tuple[str, str, str, int], None] = OrderedDict()
        self._subscribers: list[ext.AdvancedSubscriber[None] | zenoh.Subscriber[None]] = []
        history_config = (
            ext.HistoryConfig(detect_late_publishers=True, max_samples=history)
            if history > 0
            else None
        )
        self._subscribers.append(
            ext.declare_advanced_subscriber(
                self._session,
                keys.transitions(fleet, robot),
                self._on_transition,
                history=history_config,
                # Gaps in a publisher's sequence are fetched from its cache, so a transition
                # lost on the way (or raced by the history query) still arrives, in order.
                recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
            )
        )
        if errors:
            self._subscribers.append(
                self._session.declare_subscriber(keys.errors(fleet, robot), self._on_error)
            )
        self._dispatchers: list[threading.Thread] = []
        self._closed = False

    # -- callbacks (Zenoh's threads: enqueue only) ------------------------------------------

    def _on_transition(self, sample: zenoh.Sample) -> None:
        self._events.put(("Transition", sample.payload.to_bytes()))

    def _on_error(self, sample: zenoh.Sample) -> None:
        self._events.put(("Error", sample.payload.to_bytes()))

    # -- events ------------------------------------------------------------------------------

    def next_event(self, timeout_s: float | None = None) -> Transition | Error | None:
        """Return the next event, or None when ``timeout_s`` passes or the client closes."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                item = self._events.get(timeout=remaining)
            except queue.Empty:
                return None
            if not isinstance(item, tuple):  # the close marker
                self._events.put(_CLOSED)  # let every other waiter see it too
                return None
            kind: str = item[0]
            payload: bytes = item[1]
            try:
                if kind == "Transition":
                    transition = decode(payload, Transition)
                    if self._is_repeat(transition):
                        continue
                    return transition
                return decode(payload, Error)
            except WireError as exc:
                self.undecodable += 1
                log.warning("skipped an undecodable %s: %s", kind, exc)
            if deadline is not None and time.monotonic() >= deadline:
                return None

    def _is_repeat(self, t: Transition) -> bool:
        """Whether this transition was delivered before (history and live can overlap)."""
        identity = (t.fleet, t.robot, t.session, t.closed.id)
        if identity in self._seen:
            return True
        self._seen[identity] = None
        if len(self._seen) > _SEEN_KEPT:
            self._seen.popitem(last=False)
        return False

    def next_transition(self, timeout_s: float | None = None) -> Transition | None:
        """Return the next transition (errors are skipped), or None on timeout or close."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            event = self.next_event(remaining)
            if event is None or isinstance(event, Transition):
                return event

    def transitions(self, timeout_s: float | None = None) -> Iterator[Transition]:
        """Iterate over transitions until the client closes (or ``timeout_s`` of silence)."""
        while (event := self.next_transition(timeout_s)) is not None:
            yield event

    def on_transition(self, callback: Callable[[Transition], None]) -> threading.Thread:
        """Call ``callback`` with every transition, on a thread of its own, until ``close``.

        The callback runs outside Zenoh's threads, so it may block or call the client's
        queries. An exception in it is logged and the next transition still arrives.
        """

        def dispatch() -> None:
            while (transition := self.next_transition()) is not None:
                try:
                    callback(transition)
                except Exception:
                    log.exception("transition callback failed")

        thread = threading.Thread(target=dispatch, name="lessmap-fleet-callback", daemon=True)
        thread.start()
        self._dispatchers.append(thread)
        return thread

    # -- queries -----------------------------------------------------------------------------

    def state(
        self, robot: str, fleet: str | None = None, timeout_s: float = 2.0
    ) -> SessionState | None:
        """Return the robot's session state (open session, else the last closed one)."""
        found = self._get(
            keys.state(fleet or self._concrete_fleet(), robot), SessionState, timeout_s
        )
        return found[0] if found else None

    def states(self, fleet: str | None = None, timeout_s: float = 2.0) -> list[SessionState]:
        """Return the session state of every robot of a fleet (or of every fleet)."""
        return self._get(keys.state(fleet or self.fleet, "*"), SessionState, timeout_s)

    def submap(
        self, robot: str, submap_id: int, fleet: str | None = None, timeout_s: float = 2.0
    ) -> Submap | None:
        """Return one submap (closed or open) of the robot's session."""
        key = keys.submap(fleet or self._concrete_fleet(), robot, submap_id)
        found = self._get(key, Submap, timeout_s)
        return found[0] if found else None

    def submaps(self, robot: str, fleet: str | None = None, timeout_s: float = 2.0) -> list[Submap]:
        """Return every submap the service remembers for the robot's session, by id."""
        key = keys.submaps(fleet or self._concrete_fleet(), robot)
        return sorted(self._get(key, Submap, timeout_s), key=lambda s: s.summary.id)

    def health(self, timeout_s: float = 2.0) -> list[Health]:
        """Return the health of every service instance that answers."""
        return self._get(keys.health(), Health, timeout_s)

    def instances(self, timeout_s: float = 1.0) -> list[str]:
        """Return the names of the service instances alive on the network."""
        return service_instances(self._session, timeout_s)

    def _concrete_fleet(self) -> str:
        if self.fleet == "*":
            msg = "this client follows every fleet: pass fleet= to the query"
            raise ValueError(msg)
        return self.fleet

    def _get(self, key: str, expected: type[M], timeout_s: float) -> list[M]:
        results: list[M] = []
        for reply in self._session.get(key, timeout=timeout_s):
            if reply.ok is None:
                continue
            try:
                results.append(decode(reply.ok.payload.to_bytes(), expected))
            except WireError as exc:
                self.undecodable += 1
                log.warning("skipped an undecodable reply on %s: %s", reply.ok.key_expr, exc)
        return results

    # -- lifetime ----------------------------------------------------------------------------

    def close(self) -> None:
        """Stop receiving and release Zenoh resources (idempotent, never hangs)."""
        if self._closed:
            return
        self._closed = True
        for subscriber in self._subscribers:
            subscriber.undeclare()  # type: ignore[no-untyped-call]
        self._subscribers.clear()
        self._events.put(_CLOSED)
        current = threading.current_thread()
        for thread in self._dispatchers:
            if thread is not current:  # close() may be called from inside a callback
                thread.join(timeout=5.0)
        if self._owns_session:
            self._session.close()

    def __enter__(self) -> FleetClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

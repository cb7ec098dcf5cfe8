"""What a ``Connection`` needs from the network, and its Zenoh implementation.

Rules of this file:

1. A ``Transport`` moves bytes; it never decodes. Decoding, de-duplication and queueing
   belong to ``Subscription`` and ``Connection``, so the Zenoh transport and the in-process
   fake (``lessmap_client.testing``) share every line above this one.
2. ``deliver`` callbacks run on the transport's threads (Zenoh's, for ``ZenohTransport``):
   they must return at once and never call back into the transport.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any, Protocol

import zenoh
from zenoh import ext

from lessmap_client.session import service_instances
from lessmap_schemas import keys

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger(__name__)


class Handle(Protocol):
    """Something declared on a transport that must be released."""

    def close(self) -> None:
        """Release it (idempotent)."""


class Publisher(Handle, Protocol):
    """A declared publisher on one key."""

    def put(self, payload: bytes) -> None:
        """Publish one payload; blocks rather than drop it under congestion."""

    def matched(self) -> bool:
        """Whether a subscriber (the service's, for frames) matches the key right now."""


class Transport(Protocol):
    """The network under a ``Connection``: put, subscribe and query bytes by key."""

    def subscribe(
        self, key: str, deliver: Callable[[bytes], None], *, history: int | None
    ) -> Handle:
        """Call ``deliver`` with the payload of every sample on ``key``.

        Args:
            key: key expression (``*`` chunks allowed).
            deliver: called on the transport's thread; must not block.
            history: ``None`` for a plain live subscription; otherwise recover up to this
                many recent samples per publisher on joining (0: none) and recover samples
                lost in transit from the publisher's cache.
        """

    def get(self, key: str, timeout_s: float) -> list[tuple[str, bytes]]:
        """Query ``key``; return the (key, payload) of every successful reply."""

    def instances(self, timeout_s: float) -> list[str]:
        """Return the names of the lessmap service instances alive."""

    def watch_instances(self, deliver: Callable[[str, bool], None]) -> Handle:
        """Call ``deliver(instance, alive)`` for every instance token, present and to come.

        The instances alive when it is declared are delivered as ``alive=True`` first (a
        liveliness subscriber with history); then each token that appears or disappears.
        ``deliver`` runs on the transport's thread and must not block.
        """

    def publisher(self, key: str, encoding: str, cache: int) -> Publisher:
        """Declare a publisher keeping ``cache`` recent samples for late joiners."""

    def put(self, key: str, payload: bytes, encoding: str) -> None:
        """Publish one payload on ``key`` without a declared publisher."""

    def close(self) -> None:
        """Release everything still declared (idempotent)."""


class Host(Protocol):
    """What a ``RobotPublisher`` declares on: a ``Connection`` (kept apart to avoid a cycle)."""

    @property
    def transport(self) -> Transport:
        """The network under the connection."""

    def _adopt(self, child: object) -> None: ...

    def _release(self, child: object) -> None: ...

    def _check_open(self) -> None: ...


def wait_for_instances(transport: Transport, timeout_s: float) -> bool:
    """Wait until a lessmap service instance is alive; False after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        if transport.instances(min(1.0, max(0.1, remaining))):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)


class _ZenohHandle:
    def __init__(
        self, owner: ZenohTransport, entity: zenoh.Subscriber[None] | ext.AdvancedSubscriber[None]
    ) -> None:
        self._owner = owner
        self._entity: zenoh.Subscriber[None] | ext.AdvancedSubscriber[None] | None = entity

    def close(self) -> None:
        entity, self._entity = self._entity, None
        if entity is not None:
            entity.undeclare()  # type: ignore[no-untyped-call]
            self._owner._forget(self)


class _ZenohPublisher:
    def __init__(
        self,
        owner: ZenohTransport,
        publisher: ext.AdvancedPublisher,
        probe: zenoh.Publisher | None = None,
    ) -> None:
        self._owner = owner
        self._publisher: ext.AdvancedPublisher | None = publisher
        # zenoh.ext's AdvancedPublisher has no matching status in Python: a plain publisher
        # on the same key, never used to put, tells whether a subscriber matches.
        self._probe = probe

    def put(self, payload: bytes) -> None:
        if self._publisher is None:
            msg = "publisher is closed"
            raise RuntimeError(msg)
        self._publisher.put(payload)

    def matched(self) -> bool:
        probe = self._probe
        if probe is None or self._publisher is None:
            return self._publisher is not None
        # The stubs say bool; the binding returns a MatchingStatus with ``.matching``.
        status: Any = probe.matching_status
        return bool(getattr(status, "matching", status))

    def close(self) -> None:
        publisher, self._publisher = self._publisher, None
        probe, self._probe = self._probe, None
        if probe is not None:
            probe.undeclare()
        if publisher is not None:
            publisher.undeclare()
            self._owner._forget(self)


class ZenohTransport:
    """A ``Transport`` over a Zenoh session.

    Args:
        session: an open Zenoh session.
        owned: close the session with the transport (False when the caller lent it).
    """

    def __init__(self, session: zenoh.Session, *, owned: bool) -> None:
        self.session = session
        self._owned = owned
        self._lock = threading.Lock()
        self._declared: list[_ZenohHandle | _ZenohPublisher] = []
        self._closed = False

    def _remember(self, handle: _ZenohHandle | _ZenohPublisher) -> None:
        with self._lock:
            self._declared.append(handle)

    def _forget(self, handle: _ZenohHandle | _ZenohPublisher) -> None:
        with self._lock:
            if handle in self._declared:
                self._declared.remove(handle)

    def subscribe(
        self, key: str, deliver: Callable[[bytes], None], *, history: int | None
    ) -> Handle:
        """See ``Transport.subscribe``."""

        def on_sample(sample: zenoh.Sample) -> None:  # Zenoh's thread: hand over and return
            deliver(sample.payload.to_bytes())

        entity: zenoh.Subscriber[None] | ext.AdvancedSubscriber[None]
        if history is None:
            entity = self.session.declare_subscriber(key, on_sample)
        else:
            entity = ext.declare_advanced_subscriber(
                self.session,
                key,
                on_sample,
                history=(
                    ext.HistoryConfig(detect_late_publishers=True, max_samples=history)
                    if history > 0
                    else None
                ),
                # Gaps in a publisher's sequence are fetched from its cache, so a sample lost
                # on the way (or raced by the history query) still arrives, in order.
                recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
            )
        handle = _ZenohHandle(self, entity)
        self._remember(handle)
        return handle

    def get(self, key: str, timeout_s: float) -> list[tuple[str, bytes]]:
        """See ``Transport.get``.

        Every matching queryable is asked and every reply kept: several instances answer
        for one robot during a hand-over (old and new owner) on the same key, and Zenoh's
        default consolidation would keep only one of them, not necessarily the current.
        """
        replies = self.session.get(
            key,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout_s,
        )
        return [
            (str(reply.ok.key_expr), reply.ok.payload.to_bytes())
            for reply in replies
            if reply.ok is not None
        ]

    def instances(self, timeout_s: float) -> list[str]:
        """See ``Transport.instances``."""
        return service_instances(self.session, timeout_s)

    def watch_instances(self, deliver: Callable[[str, bool], None]) -> Handle:
        """See ``Transport.watch_instances``."""
        prefix = keys.instance_token("x")[:-1]

        def on_sample(sample: zenoh.Sample) -> None:  # Zenoh's thread: hand over and return
            key = str(sample.key_expr)
            if key.startswith(prefix):
                deliver(key[len(prefix) :], sample.kind == zenoh.SampleKind.PUT)

        entity = self.session.liveliness().declare_subscriber(
            keys.instances(), on_sample, history=True
        )
        handle = _ZenohHandle(self, entity)
        self._remember(handle)
        return handle

    def publisher(self, key: str, encoding: str, cache: int) -> Publisher:
        """See ``Transport.publisher``."""
        handle = _ZenohPublisher(
            self,
            ext.declare_advanced_publisher(
                self.session,
                key,
                encoding=zenoh.Encoding(encoding),
                congestion_control=zenoh.CongestionControl.BLOCK,  # never drop a frame silently
                cache=ext.CacheConfig(cache),
                publisher_detection=True,
            ),
            self.session.declare_publisher(key),
        )
        self._remember(handle)
        return handle

    def put(self, key: str, payload: bytes, encoding: str) -> None:
        """See ``Transport.put``."""
        self.session.put(
            key,
            payload,
            encoding=zenoh.Encoding(encoding),
            congestion_control=zenoh.CongestionControl.BLOCK,
        )

    def close(self) -> None:
        """Undeclare what is left (advanced entities must go before the session), then close."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            left = list(self._declared)
        for handle in left:
            handle.close()
        if self._owned:
            self.session.close()

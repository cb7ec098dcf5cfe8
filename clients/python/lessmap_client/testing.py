"""An in-process lessmap network for testing your robot code and fleet apps without a router.

In the manner of httpx's ``MockTransport``: the SDK ships the fake, your code keeps calling
the real ``Connection`` API (robots too: ``bus.frames`` holds what they published).

```python
from lessmap_client.testing import FakeBus, make_transition

bus = FakeBus()
with bus.connect() as conn, conn.subscribe_transitions("warehouse") as sub:
    bus.publish_transition(make_transition("warehouse", "amr-7"))
    assert sub.try_recv().robot == "amr-7"      # delivered before publish_transition returns
```
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from lessmap_client.connection import Connection
from lessmap_schemas import keys
from lessmap_schemas.codec import decode_inbound, encode
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.messages import (
    AreaGraph,
    Error,
    Frame,
    Health,
    SessionEnd,
    SessionState,
    Submap,
    SubmapSummary,
    Transition,
)
from lessmap_schemas.partition import partition_of

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from lessmap_client.transport import Handle, Publisher

__all__ = ["FakeBus", "Sent", "make_error", "make_state", "make_transition"]

FAKE_INSTANCE = "fake"
_UNSET: Any = object()


@dataclass(frozen=True, slots=True)
class Sent:
    """One message a robot published on the fake bus."""

    fleet: str
    robot: str
    message: Frame | SessionEnd


def key_matches(pattern: str, key: str) -> bool:
    """Whether a concrete ``key`` matches ``pattern`` (``*``: one chunk, ``**``: any)."""
    return _match(pattern.split("/"), key.split("/"))


def _match(pattern: list[str], key: list[str]) -> bool:
    if not pattern:
        return not key
    head, rest = pattern[0], pattern[1:]
    if head == "**":
        return any(_match(rest, key[i:]) for i in range(len(key) + 1) if "@" not in key[:i])
    if not key:
        return False
    chunk_ok = (head == "*" and not key[0].startswith("@")) or head == key[0]
    return chunk_ok and _match(rest, key[1:])


class FakeBus:
    """An in-process stand-in for a lessmap network: one bus, any number of connections.

    Every message goes through the wire codec, so a test also catches what a real service
    would reject. Delivery is synchronous (subscribers have the event when ``publish_*`` returns;
    handlers are still called on their subscription's thread), ``*`` matches one key chunk and
    ``**`` any number, transitions are retained (``history`` per key) for subscriptions that ask
    for history, and queries answer from what ``set_state``/``set_submap``/``set_health``
    stored. The fake is no service: publishing frames produces no transitions by itself.

    Contract v4: robots put their frames on ``lessmap/v4/<fleet>/<robot>/frames/<partition>``;
    a frames key naming another partition reaches no service and is counted in
    ``misrouted_sent``. The bus's ``instances`` are the live service instances (their liveliness
    tokens): robot publishers follow them (``status.owner``), ``coverage()`` ranks them. Events
    carry an ``epoch``: publish one with a lower epoch than an earlier one for the same robot to
    test that your app never sees a deposed owner's late event (the SDK drops it).

    Args:
        history: transitions retained per robot for subscriptions with ``history``.
        instances: service instances alive at first (their liveliness tokens): every
            partition has an owner while there is one (``wait_for_service`` is True); change
            them with ``instances = [...]``, ``add_instance`` and ``remove_instance``, which
            robot publishers on the bus follow at once.
    """

    def __init__(self, *, history: int = 64, instances: Sequence[str] = (FAKE_INSTANCE,)) -> None:
        self._history = history
        self._lock = threading.RLock()
        self._instances: list[str] = []
        self._watchers: list[_FakeWatcher] = []
        self._subscribers: list[_FakeSubscriber] = []
        self._retained: dict[str, deque[bytes]] = {}
        self._replies: dict[str, bytes] = {}
        self._sent: list[Sent] = []
        self.undecodable_sent = 0  # robot payloads that were not Frames or SessionEnds
        self.misrouted_sent = 0  # robot payloads put on a frames key of another partition
        self.instances = instances

    # -- service instances (liveliness tokens) ----------------------------------------------

    @property
    def instances(self) -> tuple[str, ...]:
        """The live service instances, in the order they appeared (read-only; assign to set)."""
        with self._lock:
            return tuple(self._instances)

    @instances.setter
    def instances(self, names: Sequence[str]) -> None:
        wanted = list(dict.fromkeys(keys.validate_name(n, "instance") for n in names))
        with self._lock:
            gone = [n for n in self._instances if n not in wanted]
            new = [n for n in wanted if n not in self._instances]
            self._instances = wanted
            for name in gone:
                self._notify(name, alive=False)
            for name in new:
                self._notify(name, alive=True)

    def add_instance(self, name: str) -> None:
        """Declare a service instance's liveliness token (no-op if it is alive)."""
        self.instances = [*self.instances, name]

    def remove_instance(self, name: str) -> None:
        """Drop a service instance's liveliness token, as when it stops or crashes."""
        self.instances = [n for n in self.instances if n != name]

    def _notify(self, name: str, *, alive: bool) -> None:
        for watcher in list(self._watchers):
            watcher.deliver(name, alive)

    def connect(self) -> Connection:
        """Open a connection to this bus (the same ``Connection`` API as ``connect()``)."""
        return Connection(_FakeTransport(self))

    # -- what the service would publish -------------------------------------------------------

    def publish_transition(self, transition: Transition) -> None:
        """Publish a transition as the service would (retained for late subscribers).

        Raises:
            ValueError: its ``partition`` is not the robot's (no service would publish it).
        """
        expected = partition_of(transition.fleet, transition.robot)
        if transition.partition != expected:
            msg = (
                f"transition of {transition.fleet}/{transition.robot} names partition "
                f"{transition.partition}; the robot is in partition {expected}"
            )
            raise ValueError(msg)
        self.put(keys.transitions(transition.fleet, transition.robot), encode(transition))

    def publish_error(self, error: Error) -> None:
        """Publish an ``Error`` on its robot's key (or the instance's key if it names none)."""
        if error.fleet is None or error.robot is None:
            key = keys.service_errors(error.instance)
        else:
            key = keys.errors(error.fleet, error.robot)
        self.put(key, encode(error))

    def put(self, key: str, payload: bytes) -> None:
        """Publish raw bytes on a concrete key (to test how your app handles garbage)."""
        with self._lock:
            if key.endswith("/transitions"):
                kept = self._retained.setdefault(key, deque(maxlen=self._history))
                kept.append(payload)
            if _is_frames_key(key):
                self._record(key, payload)
            for subscriber in list(self._subscribers):
                if key_matches(subscriber.key, key):
                    subscriber.deliver(payload)

    # -- what the service would answer ---------------------------------------------------------

    def set_state(self, state: SessionState) -> None:
        """Answer ``state``/``states`` queries for this robot with ``state``."""
        self._reply(keys.state(state.fleet, state.robot), state)

    def set_submap(self, submap: Submap) -> None:
        """Answer ``submap``/``submaps`` queries for this submap."""
        self._reply(keys.submap(submap.fleet, submap.robot, submap.summary.id), submap)

    def set_area_graph(self, graph: AreaGraph) -> None:
        """Answer ``area_graph``/``area_graphs`` queries for this robot with ``graph``."""
        self._reply(keys.areas(graph.fleet, graph.robot), graph)

    def set_health(self, health: Health) -> None:
        """Answer ``health`` queries for this instance."""
        self._reply(keys.health(health.instance), health)

    def clear_replies(self) -> None:
        """Forget every stored state, submap and health answer."""
        with self._lock:
            self._replies.clear()

    def _reply(self, key: str, message: SessionState | Submap | AreaGraph | Health) -> None:
        with self._lock:
            self._replies[key] = encode(message)

    # -- what robots published -----------------------------------------------------------------

    @property
    def sent(self) -> list[Sent]:
        """Every Frame and SessionEnd robots published, in order."""
        with self._lock:
            return list(self._sent)

    def frames(self, fleet: str | None = None, robot: str | None = None) -> list[Frame]:
        """Frames published (by one robot, a fleet, or everyone), in order."""
        return [s.message for s in self._select(fleet, robot) if isinstance(s.message, Frame)]

    def session_ends(self, fleet: str | None = None, robot: str | None = None) -> list[SessionEnd]:
        """SessionEnds published (robots send one when closed), in order."""
        return [s.message for s in self._select(fleet, robot) if isinstance(s.message, SessionEnd)]

    def _select(self, fleet: str | None, robot: str | None) -> list[Sent]:
        return [
            s
            for s in self.sent
            if (fleet is None or s.fleet == fleet) and (robot is None or s.robot == robot)
        ]

    def _record(self, key: str, payload: bytes) -> None:
        try:
            fleet, robot, _ = keys.parse_robot_key(key)
        except WireError:
            self.misrouted_sent += 1  # another partition's key: no instance subscribes to it
            return
        try:
            message = decode_inbound(payload)
        except WireError:
            self.undecodable_sent += 1
            return
        self._sent.append(Sent(fleet, robot, message))

    # -- transport side ------------------------------------------------------------------------

    def _subscribe(
        self, key: str, deliver: Callable[[bytes], None], history: int | None
    ) -> _FakeSubscriber:
        subscriber = _FakeSubscriber(self, key, deliver)
        with self._lock:
            if history:
                for retained_key, payloads in self._retained.items():
                    if key_matches(key, retained_key):
                        for payload in list(payloads)[-history:]:
                            deliver(payload)
            self._subscribers.append(subscriber)
        return subscriber

    def _unsubscribe(self, subscriber: _FakeSubscriber) -> None:
        with self._lock:
            if subscriber in self._subscribers:
                self._subscribers.remove(subscriber)

    def _watch(self, deliver: Callable[[str, bool], None]) -> _FakeWatcher:
        watcher = _FakeWatcher(self, deliver)
        with self._lock:
            for name in self._instances:  # history: the tokens alive now
                deliver(name, True)
            self._watchers.append(watcher)
        return watcher

    def _unwatch(self, watcher: _FakeWatcher) -> None:
        with self._lock:
            if watcher in self._watchers:
                self._watchers.remove(watcher)

    def _get(self, key: str) -> list[tuple[str, bytes]]:
        with self._lock:
            return [(k, v) for k, v in self._replies.items() if key_matches(key, k)]


class _FakeSubscriber:
    def __init__(self, bus: FakeBus, key: str, deliver: Callable[[bytes], None]) -> None:
        self.bus = bus
        self.key = key
        self.deliver = deliver

    def close(self) -> None:
        self.bus._unsubscribe(self)


class _FakeWatcher:
    def __init__(self, bus: FakeBus, deliver: Callable[[str, bool], None]) -> None:
        self.bus = bus
        self.deliver = deliver

    def close(self) -> None:
        self.bus._unwatch(self)


def _is_frames_key(key: str) -> bool:
    parts = key.split("/")
    return len(parts) >= 5 and parts[4] == "frames"


class _FakePublisher:
    def __init__(self, bus: FakeBus, key: str) -> None:
        self._bus = bus
        self._key = key
        self._closed = False

    def put(self, payload: bytes) -> None:
        if self._closed:
            msg = "publisher is closed"
            raise RuntimeError(msg)
        self._bus.put(self._key, payload)

    def matched(self) -> bool:
        return not self._closed

    def close(self) -> None:
        self._closed = True


class _FakeTransport:
    """The ``Transport`` of one fake connection."""

    def __init__(self, bus: FakeBus) -> None:
        self._bus = bus
        self._closed = False

    def _check(self) -> None:
        if self._closed:
            msg = "the fake connection is closed"
            raise RuntimeError(msg)

    def subscribe(
        self, key: str, deliver: Callable[[bytes], None], *, history: int | None
    ) -> Handle:
        self._check()
        return self._bus._subscribe(key, deliver, history)

    def get(self, key: str, timeout_s: float) -> list[tuple[str, bytes]]:
        self._check()
        return self._bus._get(key)

    def instances(self, timeout_s: float) -> list[str]:
        self._check()
        return list(self._bus.instances)

    def watch_instances(self, deliver: Callable[[str, bool], None]) -> Handle:
        self._check()
        return self._bus._watch(deliver)

    def publisher(self, key: str, encoding: str, cache: int) -> Publisher:
        self._check()
        return _FakePublisher(self._bus, key)

    def put(self, key: str, payload: bytes, encoding: str) -> None:
        self._check()
        self._bus.put(key, payload)

    def close(self) -> None:
        self._closed = True


# -- message builders ------------------------------------------------------------------------


def make_transition(
    fleet: str,
    robot: str,
    *,
    closed_id: int = 0,
    seq: int | None = None,
    session: str = "s0",
    incarnation: int = 0,
    reason: Literal["SPECTRAL", "DISCONNECTED"] = "SPECTRAL",
    closed_features: Sequence[int] = (1, 2, 3),
    opened_features: Sequence[int] = (3, 4, 5),
    instance: str = FAKE_INSTANCE,
    epoch: int = 1,
) -> Transition:
    """Return a consistent ``Transition``: submap ``closed_id`` closed, the next one opened.

    Frames are numbered 10 per submap unless ``seq`` (the detection frame) is given. The
    partition is the robot's; ``epoch`` is the producing owner's ownership epoch (a later
    owner has a higher one).
    """
    first = closed_id * 10
    detect = first + 10 if seq is None else seq
    boundary = max(first + 1, detect - 1) if detect > first else detect
    spectral = reason == "SPECTRAL"
    return Transition(
        fleet=fleet,
        robot=robot,
        session=session,
        incarnation=incarnation,
        seq=detect,
        boundary_seq=boundary,
        stamp_s=float(detect),
        reason=reason,
        ncut=0.05 if spectral else None,
        lambda2=0.01 if spectral else None,
        closed=SubmapSummary(
            id=closed_id,
            first_seq=first,
            last_seq=max(first, boundary - 1),
            frame_count=max(1, boundary - first),
            features=sorted(set(closed_features)),
        ),
        opened=SubmapSummary(
            id=closed_id + 1,
            first_seq=boundary,
            last_seq=detect,
            frame_count=detect - boundary + 1,
            features=sorted(set(opened_features)),
        ),
        boundary_features=sorted(set(closed_features) & set(opened_features)),
        area=closed_id + 1,
        left_area=closed_id,
        revisit=False,
        batch_frames=1,
        instance=instance,
        partition=partition_of(fleet, robot),
        epoch=epoch,
    )


def make_state(
    fleet: str,
    robot: str,
    *,
    session: str = "s0",
    open: bool = True,
    frames_applied: int = 0,
    transitions: int = 0,
    instance: str = FAKE_INSTANCE,
    epoch: int = 1,
) -> SessionState:
    """Return a ``SessionState`` with ``transitions`` closed submaps and consistent counters.

    ``epoch`` is the answering instance's ownership epoch (the highest reply is current).
    """
    closed = [
        SubmapSummary(id=i, first_seq=i * 10, last_seq=i * 10 + 9, frame_count=10, features=[])
        for i in range(transitions)
    ]
    last = frames_applied - 1 if frames_applied else None
    first = transitions * 10
    current = SubmapSummary(
        id=transitions,
        first_seq=first,
        last_seq=max(first, last or 0),
        frame_count=max(0, frames_applied - 10 * transitions),
        features=[],
    )
    return SessionState(
        fleet=fleet,
        robot=robot,
        session=session,
        incarnation=0,
        instance=instance,
        epoch=epoch,
        open=open,
        last_seq=last,
        frames_applied=frames_applied,
        frames_duplicate=0,
        frames_missing=0,
        frames_rejected=0,
        transitions=transitions,
        method="paper",
        current_area=transitions,
        current_submap=current,
        closed_submaps=closed,
        nodes=0,
        edges=0,
    )


def make_error(
    fleet: str | None,
    robot: str | None,
    code: ErrorCode | str = ErrorCode.SEQ_GAP,
    detail: str = "reported by the fake bus",
    *,
    session: str | None = None,
    seq: int | None = None,
    instance: str = FAKE_INSTANCE,
    epoch: int | None = _UNSET,
) -> Error:
    """Return an ``Error`` report as the service would publish it.

    ``epoch`` defaults to 1 for an error about a robot and to None (unattributable) for one
    that names no robot.
    """
    if epoch is _UNSET:
        epoch = 1 if fleet is not None and robot is not None else None
    return Error(
        fleet=fleet,
        robot=robot,
        session=session,
        code=ErrorCode(code),
        detail=detail,
        seq=seq,
        stamp_s=time.time(),
        instance=instance,
        epoch=epoch,
    )

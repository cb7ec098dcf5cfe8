"""``connect()`` and ``Connection``: everything a robot or a fleet app declares, in one place.

The shape of zenoh-python's ``with zenoh.open(conf) as session`` and nats.py's
``nc = await nats.connect()``: open once, declare robots and subscriptions from the
connection, each subscription owning its queue or handler, and query through it. Closing the
connection closes everything declared from it.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any, TypeVar

from lessmap_client.fencing import current_area_graphs, current_states
from lessmap_client.fleet_areas import FleetGraph, FleetParams, fleet_graph_of
from lessmap_client.robot import DEFAULT_CLOSE_TIMEOUT_S, RobotPublisher, close_all
from lessmap_client.session import DEFAULT_ENDPOINT, open_session
from lessmap_client.subscription import DEFAULT_MAXSIZE, Subscription
from lessmap_client.transport import ZenohTransport, wait_for_instances
from lessmap_schemas import keys, partition
from lessmap_schemas.codec import decode
from lessmap_schemas.errors import WireError
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits
from lessmap_schemas.messages import AreaGraph, Error, Health, SessionState, Submap, Transition

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from types import TracebackType

    import zenoh

    from lessmap_client.transport import Transport

log = logging.getLogger(__name__)

M = TypeVar("M", SessionState, Submap, AreaGraph, Health)

#: Recent transitions per robot recovered on joining when ``history=True``.
DEFAULT_HISTORY = 64


def connect(
    endpoints: str | Sequence[str] = DEFAULT_ENDPOINT,
    *,
    mode: str = "client",
    timeout_s: float = 10.0,
    config_file: str | None = None,
    listen: Sequence[str] = (),
) -> Connection:
    """Open a connection to a lessmap network (use it as a context manager).

    Args:
        endpoints: Zenoh endpoint(s) of the lessmap router, by default the embedded router of
            ``lessmap serve`` on this machine (``tcp/127.0.0.1:7447``).
        mode: Zenoh mode, ``"client"`` (through the router) or ``"peer"``.
        timeout_s: how long to retry while no router answers.
        config_file: a Zenoh JSON5 config to start from (TLS, credentials, ...); its
            endpoints are used when ``endpoints`` is empty.
        listen: endpoints to listen on (peer mode).

    Multicast scouting is always off: the endpoints are explicit.

    Raises:
        ConnectionError: no router could be reached within ``timeout_s``.
        ZenohConfigError: the configuration is invalid, or a listen port is taken.
    """
    targets = [endpoints] if isinstance(endpoints, str) else list(endpoints)
    session = open_session(targets, mode, timeout_s, config_file, listen=listen)
    log.info("connected to %s (%s mode)", ", ".join(targets) or config_file, mode)
    return Connection(ZenohTransport(session, owned=True))


class Connection:
    """An open connection to a lessmap network, from which everything is declared.

    Made by ``connect()`` (Zenoh), ``Connection.from_session`` (a Zenoh session you own) or
    ``lessmap_client.testing.FakeBus.connect()`` (in-process, for your tests).

    Args:
        transport: the network under the connection.
    """

    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.undecodable = 0  # query replies that were not valid messages (logged, skipped)
        self._lock = threading.Lock()
        self._children: dict[int, Any] = {}
        self._closed = False

    @classmethod
    def from_session(cls, session: zenoh.Session) -> Connection:
        """Wrap an open Zenoh session; closing the connection leaves the session open."""
        return cls(ZenohTransport(session, owned=False))

    # -- robots ------------------------------------------------------------------------------

    def robot(
        self,
        fleet: str,
        robot: str,
        *,
        session_id: str | None = None,
        cache: int = 1000,
        limits: WireLimits = DEFAULT_LIMITS,
        on_error: Callable[[Error], None] | None = None,
        auto_new_session: bool = True,
    ) -> RobotPublisher:
        """Declare a robot publisher: frames numbered from 0 in a fresh session.

        It follows the service's reports about its session (``status``, ``on_error``,
        ``state()``) and starts a new session when the service closed its own, unless
        ``auto_new_session=False``. See ``RobotPublisher`` for the arguments. Closing it (or
        this connection) sends the ``SessionEnd``.
        """
        return RobotPublisher(
            fleet,
            robot,
            session=self,
            session_id=session_id,
            cache=cache,
            limits=limits,
            on_error=on_error,
            auto_new_session=auto_new_session,
        )

    # -- subscriptions -----------------------------------------------------------------------

    def subscribe_transitions(
        self,
        fleet: str = "*",
        robot: str = "*",
        *,
        history: bool | int = True,
        handler: Callable[[Transition], None] | None = None,
        maxsize: int = DEFAULT_MAXSIZE,
    ) -> Subscription[Transition]:
        """Subscribe to the transitions of one robot, a fleet (``robot="*"``) or everything.

        Args:
            fleet: fleet name or ``"*"``.
            robot: robot name or ``"*"``.
            history: recover recent transitions on joining: True for the last 64 per robot,
                an int for that many, False or 0 for live ones only. Transitions lost in
                transit are recovered from the service's cache either way.
            handler: called with every transition on this subscription's own thread; without
                it, read the subscription (``for t in sub``, ``recv``, ``try_recv``).
            maxsize: events buffered before new ones are dropped and counted.
        """
        depth = DEFAULT_HISTORY if history is True else int(history)
        return self._subscribe(
            f"transitions {fleet}/{robot}",
            _decode_transition,
            [(keys.transitions(fleet, robot), depth)],
            handler,
            maxsize,
        )

    def subscribe_errors(
        self,
        fleet: str = "*",
        robot: str = "*",
        *,
        handler: Callable[[Error], None] | None = None,
        maxsize: int = DEFAULT_MAXSIZE,
    ) -> Subscription[Error]:
        """Subscribe to the service's ``Error`` reports about these robots' input (live only)."""
        return self._subscribe(
            f"errors {fleet}/{robot}",
            _decode_error,
            [(keys.errors(fleet, robot), None)],
            handler,
            maxsize,
        )

    def subscribe_events(
        self,
        fleet: str = "*",
        robot: str = "*",
        *,
        history: bool | int = True,
        handler: Callable[[Transition | Error], None] | None = None,
        maxsize: int = DEFAULT_MAXSIZE,
    ) -> Subscription[Transition | Error]:
        """Subscribe to transitions and errors together, in one queue, in arrival order."""
        depth = DEFAULT_HISTORY if history is True else int(history)
        return self._subscribe(
            f"events {fleet}/{robot}",
            _decode_event,
            [(keys.transitions(fleet, robot), depth), (keys.errors(fleet, robot), None)],
            handler,
            maxsize,
        )

    def _subscribe(
        self,
        name: str,
        decoder: Callable[[bytes], Any],
        sources: list[tuple[str, int | None]],
        handler: Callable[[Any], None] | None,
        maxsize: int,
    ) -> Subscription[Any]:
        self._check_open()
        sub: Subscription[Any] = Subscription(
            decoder, name=name, maxsize=maxsize, handler=handler, on_close=self._release
        )
        self._adopt(sub)
        try:
            for key, history in sources:
                sub._attach(self.transport.subscribe(key, sub._push, history=history))
        except BaseException:
            sub.close()
            raise
        log.debug("subscribed: %s", name)
        return sub

    # -- queries -----------------------------------------------------------------------------

    def state(self, fleet: str, robot: str, timeout_s: float = 2.0) -> SessionState | None:
        """Return the robot's session state (its open session, else the last closed one).

        Of several replies (an old and a new owner of the robot's partition), the one with
        the highest ``epoch`` is current; between equal epochs, the most ``frames_applied``.
        """
        found = current_states(self._get(keys.state(fleet, robot), SessionState, timeout_s))
        return found[0] if found else None

    def states(
        self, fleet: str = "*", robot: str = "*", timeout_s: float = 2.0
    ) -> list[SessionState]:
        """Return the session state of every robot of a fleet (or of every fleet).

        One state per robot: of several replies for one robot, the one with the highest
        ``epoch`` (then the most ``frames_applied``), as ``state`` does.
        """
        return current_states(self._get(keys.state(fleet, robot), SessionState, timeout_s))

    def area_graph(self, fleet: str, robot: str, timeout_s: float = 2.0) -> AreaGraph | None:
        """Return the areas and passages of the robot's session, None if unknown.

        Of several replies, the highest ``epoch`` is current (as for ``state``).
        """
        found = current_area_graphs(self._get(keys.areas(fleet, robot), AreaGraph, timeout_s))
        return found[0] if found else None

    def area_graphs(
        self, fleet: str = "*", robot: str = "*", timeout_s: float = 2.0
    ) -> list[AreaGraph]:
        """Return the area graph of every robot of a fleet (or of every fleet), one per robot."""
        return current_area_graphs(self._get(keys.areas(fleet, robot), AreaGraph, timeout_s))

    def fleet_area_graph(
        self, fleet: str, params: FleetParams | None = None, timeout_s: float = 2.0
    ) -> FleetGraph:
        """Return the places of one fleet: its robots' area graphs merged (``fleet_areas``).

        With ``FleetParams(shared_features=True)`` (the fleet's feature ids are global:
        fiducials, a shared landmark map) areas of different robots that hold the same
        features are one fleet area, and ``area_of[(robot, area)]`` names it; without, each
        robot area is a fleet area of its own. The graphs come from whichever instances own
        the robots now (one query for the fleet, the highest epoch per robot), so a fleet
        spread over several instances merges as one. Fleet ids name this graph's areas only:
        compare ``members`` across calls.
        """
        if "*" in fleet:
            msg = f"fleet_area_graph merges one fleet, not {fleet!r}"
            raise ValueError(msg)
        return fleet_graph_of(self.area_graphs(fleet, "*", timeout_s), params)

    def submap(
        self, fleet: str, robot: str, submap_id: int, timeout_s: float = 2.0
    ) -> Submap | None:
        """Return one submap (closed or open) of the robot's session, None if unknown."""
        found = self._get(keys.submap(fleet, robot, submap_id), Submap, timeout_s)
        return found[0] if found else None

    def submaps(self, fleet: str, robot: str, timeout_s: float = 2.0) -> list[Submap]:
        """Return every submap the service remembers for the robot's session, by id."""
        found = self._get(keys.submaps(fleet, robot), Submap, timeout_s)
        return sorted(found, key=lambda s: s.summary.id)

    def health(self, timeout_s: float = 2.0) -> list[Health]:
        """Return the health of every service instance that answers."""
        return self._get(keys.health(), Health, timeout_s)

    def instances(self, timeout_s: float = 1.0) -> list[str]:
        """Return the names of the service instances alive on the network (their tokens)."""
        self._check_open()
        return sorted(set(self.transport.instances(timeout_s)))

    def coverage(self, timeout_s: float = 1.0) -> dict[int, tuple[str | None, str | None]]:
        """Return ``{partition: (owner, standby)}`` for every partition, from the live tokens.

        Computed by rendezvous hashing over the instances alive now (contract section 2a),
        as every instance computes it: with at least one instance alive every partition has
        an owner, with two or more a standby too. ``(None, None)`` everywhere means no
        instance is alive, so no robot is served. An instance that has just joined or left
        may take a moment to act on it: ``Health.partitions`` tells what it serves.
        """
        return partition.assignment(self.instances(timeout_s))

    def wait_for_service(self, timeout_s: float = 10.0) -> bool:
        """Wait until a lessmap service instance is alive; False after ``timeout_s``.

        With one instance alive every partition has an owner (``coverage``), so every robot
        is served. A robot publisher's own ``wait_for_service`` waits for its partition.
        """
        self._check_open()
        return wait_for_instances(self.transport, timeout_s)

    def _get(self, key: str, expected: type[M], timeout_s: float) -> list[M]:
        self._check_open()
        results: list[M] = []
        for reply_key, payload in self.transport.get(key, timeout_s):
            try:
                results.append(decode(payload, expected))
            except WireError as exc:
                self.undecodable += 1
                log.warning("skipped an undecodable reply on %s: %s", reply_key, exc)
        return results

    # -- lifetime ----------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """Whether ``close`` was called."""
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            msg = "the connection is closed"
            raise RuntimeError(msg)

    def _adopt(self, child: object) -> None:
        """Close ``child`` (a subscription or robot) when this connection closes."""
        with self._lock:
            self._children[id(child)] = child

    def _release(self, child: object) -> None:
        with self._lock:
            self._children.pop(id(child), None)

    def close(self, timeout_s: float = DEFAULT_CLOSE_TIMEOUT_S) -> None:
        """End every robot, close every subscription, then the network (idempotent).

        The robots end together, as ``close_all`` ends them: every ``SessionEnd`` first,
        then one wait of at most ``timeout_s`` for the service to confirm them all, whatever
        their number (``RobotPublisher.close`` has the rules; ``timeout_s=0`` does not
        wait). Subscriptions close after the robots, so they still receive what the robots'
        last frames produce while the ends are confirmed. Never raises; never waits past
        ``timeout_s`` (plus releasing what was declared).
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            children = list(self._children.values())
            self._children.clear()
        robots = [child for child in children if isinstance(child, RobotPublisher)]
        try:
            close_all(robots, timeout_s)
        except Exception:
            log.exception("closing %d robot(s) failed", len(robots))
        for child in children:
            if isinstance(child, RobotPublisher):
                continue
            try:
                child.close()
            except Exception:
                log.exception("closing %r failed", child)
        self.transport.close()

    def __enter__(self) -> Connection:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _decode_transition(payload: bytes) -> Transition:
    return decode(payload, Transition)


def _decode_error(payload: bytes) -> Error:
    return decode(payload, Error)


def _decode_event(payload: bytes) -> Transition | Error:
    event = decode(payload, (Transition, Error))
    assert isinstance(event, Transition | Error)  # decode returns one of the types asked for
    return event

"""``FleetClient``: the fleet-app API of lessmap-client 0.1, kept as a thin layer.

New code uses ``connect()`` and declares subscriptions from the ``Connection``. A
``FleetClient`` is one ``Connection`` plus one ``Subscription`` read by ``next_event``; each
``on_transition`` callback gets a subscription of its own, so every callback sees every
transition.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from lessmap_client.connection import Connection, connect
from lessmap_client.fleet_areas import FleetGraph, FleetParams
from lessmap_client.session import DEFAULT_ENDPOINT
from lessmap_schemas.messages import AreaGraph, Error, Health, SessionState, Submap, Transition

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence
    from types import TracebackType

    import zenoh

    from lessmap_client.subscription import Subscription


class FleetClient:
    """Typed events and queries for a fleet app.

    Args:
        fleet: fleet name, or ``"*"`` for every fleet.
        robot: robot name, or ``"*"`` for every robot of the fleet(s).
        session: a ``Connection`` or a Zenoh session to reuse; by default a connection is
            opened to ``connect`` and closed with the client.
        connect: endpoints of the lessmap router (used only when ``session`` is None).
        history: recent transitions per robot to recover on joining (0: live only).
        errors: also receive the service's ``Error`` events for these robots.
    """

    def __init__(
        self,
        fleet: str = "*",
        robot: str = "*",
        *,
        session: Connection | zenoh.Session | None = None,
        connect: Sequence[str] = (DEFAULT_ENDPOINT,),
        history: int = 64,
        errors: bool = False,
    ) -> None:
        self.fleet = fleet
        self.robot = robot
        self._history = history
        if isinstance(session, Connection):
            self._conn, self._owns_connection = session, False
        elif session is not None:
            self._conn, self._owns_connection = Connection.from_session(session), True
        else:
            self._conn, self._owns_connection = _open(connect), True
        self._events: Subscription[Transition | Error] | Subscription[Transition]
        if errors:
            self._events = self._conn.subscribe_events(fleet, robot, history=history)
        else:
            self._events = self._conn.subscribe_transitions(fleet, robot, history=history)
        self._callbacks: list[Subscription[Transition]] = []
        self._closed = False

    @property
    def connection(self) -> Connection:
        """The connection this client declares on."""
        return self._conn

    @property
    def dropped_stale(self) -> int:
        """Events dropped for an epoch below the robot's highest (a deposed owner's)."""
        return sum(s.dropped_stale for s in [self._events, *self._callbacks])

    @property
    def duplicates(self) -> int:
        """Transitions dropped as repeats of one already delivered (same identity)."""
        return sum(s.duplicates for s in [self._events, *self._callbacks])

    @property
    def undecodable(self) -> int:
        """Events and replies that were not valid messages (logged, skipped)."""
        subs = [self._events, *self._callbacks]
        return self._conn.undecodable + sum(s.undecodable for s in subs)

    # -- events ------------------------------------------------------------------------------

    def next_event(self, timeout_s: float | None = None) -> Transition | Error | None:
        """Return the next event, or None when ``timeout_s`` passes or the client closes.

        Events are fenced (a robot's event with an epoch below the highest seen for it is
        dropped, ``dropped_stale``) and transitions de-duplicated by identity.
        """
        return self._events.recv(timeout_s)

    def next_transition(self, timeout_s: float | None = None) -> Transition | None:
        """Return the next transition (errors are skipped), or None on timeout or close."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            event = self._events.recv(remaining)
            if event is None or isinstance(event, Transition):
                return event

    def transitions(self, timeout_s: float | None = None) -> Iterator[Transition]:
        """Iterate over transitions until the client closes (or ``timeout_s`` of silence)."""
        while (event := self.next_transition(timeout_s)) is not None:
            yield event

    def on_transition(self, callback: Callable[[Transition], None]) -> threading.Thread:
        """Call ``callback`` with every transition, on a thread of its own, until ``close``.

        Each callback has a subscription of its own: it receives every transition (history
        included), independently of ``next_transition`` and of other callbacks. It runs
        outside Zenoh's threads, so it may block or query; an exception in it is logged.
        """
        sub = self._conn.subscribe_transitions(
            self.fleet, self.robot, history=self._history, handler=callback
        )
        self._callbacks.append(sub)
        assert sub._dispatcher is not None
        return sub._dispatcher

    # -- queries -----------------------------------------------------------------------------

    def state(
        self, robot: str, fleet: str | None = None, timeout_s: float = 2.0
    ) -> SessionState | None:
        """Return the robot's session state (open session, else the last closed one)."""
        return self._conn.state(fleet or self._concrete_fleet(), robot, timeout_s)

    def states(self, fleet: str | None = None, timeout_s: float = 2.0) -> list[SessionState]:
        """Return the session state of every robot of a fleet (or of every fleet).

        One per robot: of several replies, the highest ``epoch``, then the most
        ``frames_applied``.
        """
        return self._conn.states(fleet or self.fleet, "*", timeout_s)

    def area_graph(
        self, robot: str, fleet: str | None = None, timeout_s: float = 2.0
    ) -> AreaGraph | None:
        """Return the robot's areas and the passages between them (``AreaGraph``).

        Under the ``paper`` method every submap is an area of its own; under ``areas`` a
        revisited area keeps its id.
        """
        return self._conn.area_graph(fleet or self._concrete_fleet(), robot, timeout_s)

    def area_graphs(self, fleet: str | None = None, timeout_s: float = 2.0) -> list[AreaGraph]:
        """Return the area graph of every robot of a fleet (or of every fleet), one per robot."""
        return self._conn.area_graphs(fleet or self.fleet, "*", timeout_s)

    def fleet_area_graph(
        self,
        fleet: str | None = None,
        *,
        shared_features: bool = False,
        params: FleetParams | None = None,
        timeout_s: float = 2.0,
    ) -> FleetGraph:
        """Return the fleet's places: every robot's areas merged (``Connection.fleet_area_graph``).

        ``shared_features=True`` when the fleet's feature ids are global (fiducials, a shared
        landmark map): robots that have been in the same place then share its fleet area.
        ``params`` sets every threshold of the merge (``lessmap_client.fleet_areas``).
        """
        if params is None:
            params = FleetParams(shared_features=shared_features)
        return self._conn.fleet_area_graph(fleet or self._concrete_fleet(), params, timeout_s)

    def submap(
        self, robot: str, submap_id: int, fleet: str | None = None, timeout_s: float = 2.0
    ) -> Submap | None:
        """Return one submap (closed or open) of the robot's session."""
        return self._conn.submap(fleet or self._concrete_fleet(), robot, submap_id, timeout_s)

    def submaps(self, robot: str, fleet: str | None = None, timeout_s: float = 2.0) -> list[Submap]:
        """Return every submap the service remembers for the robot's session, by id."""
        return self._conn.submaps(fleet or self._concrete_fleet(), robot, timeout_s)

    def health(self, timeout_s: float = 2.0) -> list[Health]:
        """Return the health of every service instance that answers."""
        return self._conn.health(timeout_s)

    def instances(self, timeout_s: float = 1.0) -> list[str]:
        """Return the names of the service instances alive on the network."""
        return self._conn.instances(timeout_s)

    def coverage(self, timeout_s: float = 1.0) -> dict[int, tuple[str | None, str | None]]:
        """Return ``{partition: (owner, standby)}`` from the live instances; see ``Connection``."""
        return self._conn.coverage(timeout_s)

    def wait_for_service(self, timeout_s: float = 10.0) -> bool:
        """Wait until a service instance is alive (then every partition has an owner)."""
        return self._conn.wait_for_service(timeout_s)

    def _concrete_fleet(self) -> str:
        if self.fleet == "*":
            msg = "this client follows every fleet: pass fleet= to the query"
            raise ValueError(msg)
        return self.fleet

    # -- lifetime ----------------------------------------------------------------------------

    def close(self) -> None:
        """Stop receiving and release Zenoh resources (idempotent, never hangs)."""
        if self._closed:
            return
        self._closed = True
        for sub in [self._events, *self._callbacks]:
            sub.close()
        if self._owns_connection:
            self._conn.close()

    def __enter__(self) -> FleetClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _open(endpoints: Sequence[str]) -> Connection:
    return connect(list(endpoints))

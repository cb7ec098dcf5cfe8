"""The SDK for asyncio: the same ``Connection`` API, awaited.

```python
from lessmap_client import aio

async with aio.connect() as conn:
    async with conn.subscribe_transitions("warehouse") as sub:
        async for t in sub:
            states = await conn.states("warehouse")
```

Built on the threaded SDK, so both behave the same: a subscription's handler thread hands
each event to the loop (``call_soon_threadsafe``) into a bounded ``asyncio.Queue`` (full: the
event is dropped and counted in ``dropped``); blocking calls run in ``asyncio.to_thread``.
"""

from __future__ import annotations

import asyncio
import logging
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from lessmap_client import connection as _sync
from lessmap_client.robot import DEFAULT_CLOSE_TIMEOUT_S
from lessmap_client.session import DEFAULT_ENDPOINT
from lessmap_client.subscription import DEFAULT_MAXSIZE
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits

if TYPE_CHECKING:
    from collections.abc import AsyncIterator, Callable, Iterable, Sequence
    from types import TracebackType

    from lessmap_client.fleet_areas import FleetGraph, FleetParams
    from lessmap_client.robot import RobotPublisher, RobotStatus
    from lessmap_client.subscription import Subscription
    from lessmap_schemas.messages import (
        AreaGraph,
        Error,
        Health,
        SessionState,
        Submap,
        Transition,
    )

__all__ = ["AsyncConnection", "AsyncRobotPublisher", "AsyncSubscription", "connect"]

log = logging.getLogger(__name__)

T = TypeVar("T")

_CLOSED: Any = object()


@asynccontextmanager
async def connect(
    endpoints: str | Sequence[str] = DEFAULT_ENDPOINT,
    *,
    mode: str = "client",
    timeout_s: float = 10.0,
    config_file: str | None = None,
) -> AsyncIterator[AsyncConnection]:
    """Open a connection (``async with aio.connect() as conn``); see ``lessmap_client.connect``."""
    conn = await asyncio.to_thread(
        _sync.connect, endpoints, mode=mode, timeout_s=timeout_s, config_file=config_file
    )
    async with AsyncConnection(conn) as aconn:
        yield aconn


class AsyncSubscription(Generic[T]):
    """A subscription read with ``async for`` or ``await recv()``.

    Made by ``AsyncConnection.subscribe_*``. Its events come from a threaded
    ``Subscription`` with a handler, which puts them into this loop's queue.
    """

    def __init__(self, maxsize: int) -> None:
        self._loop = asyncio.get_running_loop()
        self._queue: asyncio.Queue[T] = asyncio.Queue(maxsize)
        self._sub: Subscription[T] | None = None
        self._dropped = 0
        self._closed = False

    def _attach(self, sub: Subscription[T]) -> None:
        self._sub = sub

    def _from_thread(self, event: T) -> None:
        """The threaded subscription's handler: hand over to the loop, never wait for it."""
        try:
            self._loop.call_soon_threadsafe(self._enqueue, event)
        except RuntimeError:  # the loop is closed: nobody is reading anymore
            self._dropped += 1

    def _enqueue(self, event: T) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait(event)
        except asyncio.QueueFull:
            self._dropped += 1

    @property
    def dropped(self) -> int:
        """Events dropped because the queue was full (here or in the threaded layer)."""
        return self._dropped + (self._sub.dropped if self._sub is not None else 0)

    @property
    def duplicates(self) -> int:
        """Transitions skipped as repeats."""
        return self._sub.duplicates if self._sub is not None else 0

    @property
    def dropped_stale(self) -> int:
        """Events dropped for an epoch below the robot's highest (see ``Subscription``)."""
        return self._sub.dropped_stale if self._sub is not None else 0

    @property
    def undecodable(self) -> int:
        """Events that were not valid messages (logged, skipped)."""
        return self._sub.undecodable if self._sub is not None else 0

    async def recv(self, timeout_s: float | None = None) -> T | None:
        """Return the next event; None after ``timeout_s``, or once closed and drained."""
        if self._closed and self._queue.empty():
            return None
        try:
            event = await asyncio.wait_for(self._queue.get(), timeout_s)
        except TimeoutError:
            return None
        return None if event is _CLOSED else event

    def try_recv(self) -> T | None:
        """Return the next event if one is waiting, else None."""
        try:
            event = self._queue.get_nowait()
        except asyncio.QueueEmpty:
            return None
        return None if event is _CLOSED else event

    def __aiter__(self) -> AsyncSubscription[T]:
        return self

    async def __anext__(self) -> T:
        event = await self.recv()
        if event is None:
            raise StopAsyncIteration
        return event

    async def close(self) -> None:
        """Stop receiving; ``async for`` loops end once the queued events are read."""
        if self._closed:
            return
        self._closed = True
        if self._sub is not None:
            await asyncio.to_thread(self._sub.close)
        # Wake readers; the marker may replace the newest event only when the queue is full.
        if self._queue.full():
            self._queue.get_nowait()
            self._dropped += 1
        self._queue.put_nowait(_CLOSED)

    async def __aenter__(self) -> AsyncSubscription[T]:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()


class AsyncRobotPublisher:
    """A ``RobotPublisher`` whose blocking calls run off the event loop, in order."""

    def __init__(self, robot: RobotPublisher) -> None:
        self.sync = robot
        self.fleet = robot.fleet
        self.robot = robot.robot
        self._lock = asyncio.Lock()  # one put at a time keeps the frames in seq order

    @property
    def partition(self) -> int:
        """The robot's partition (the last chunk of its frames key)."""
        return self.sync.partition

    @property
    def session_id(self) -> str:
        """The current session id (it changes when a new session starts)."""
        return self.sync.session_id

    @property
    def next_seq(self) -> int:
        """Seq the next frame will carry."""
        return self.sync.next_seq

    @property
    def status(self) -> RobotStatus:
        """What the service reported about this robot; see ``RobotPublisher.status``."""
        return self.sync.status

    async def state(self, timeout_s: float = 2.0) -> SessionState | None:
        """The service's state of the current session; see ``RobotPublisher.state``."""
        return await asyncio.to_thread(self.sync.state, timeout_s)

    async def wait_for_service(self, timeout_s: float = 10.0) -> bool:
        """Wait until the robot's partition has an owner serving it; see ``RobotPublisher``."""
        return await asyncio.to_thread(self.sync.wait_for_service, timeout_s)

    async def new_session(self, session_id: str | None = None) -> str:
        """End the current session and start a new one at seq 0."""
        async with self._lock:
            return await asyncio.to_thread(self.sync.new_session, session_id)

    async def publish(
        self,
        features: Iterable[int],
        *,
        stamp_s: float | None = None,
        pose: tuple[float, float, float] | None = None,
        seq: int | None = None,
    ) -> int:
        """Publish one frame and return its seq; see ``RobotPublisher.publish``."""
        async with self._lock:
            return await asyncio.to_thread(
                self.sync.publish, list(features), stamp_s=stamp_s, pose=pose, seq=seq
            )

    async def close(self, timeout_s: float = DEFAULT_CLOSE_TIMEOUT_S) -> None:
        """End the session and release the publisher; see ``RobotPublisher.close``.

        The wait for the service to confirm the end (at most ``timeout_s``) runs in a
        worker thread: the event loop goes on meanwhile.
        """
        async with self._lock:
            await asyncio.to_thread(self.sync.close, timeout_s)

    async def __aenter__(self) -> AsyncRobotPublisher:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()


class AsyncConnection:
    """The asyncio face of a ``Connection``; closing it closes the connection.

    Wrap any open connection, e.g. a fake one: ``AsyncConnection(FakeBus().connect())``.
    """

    def __init__(self, conn: _sync.Connection) -> None:
        self.sync = conn
        self._subs: list[AsyncSubscription[Any]] = []

    async def robot(
        self,
        fleet: str,
        robot: str,
        *,
        session_id: str | None = None,
        cache: int = 1000,
        limits: WireLimits = DEFAULT_LIMITS,
        on_error: Callable[[Error], None] | None = None,
        auto_new_session: bool = True,
    ) -> AsyncRobotPublisher:
        """Declare a robot publisher; see ``Connection.robot``.

        ``on_error`` is called on the robot's own thread, not the event loop: use
        ``loop.call_soon_threadsafe`` from it to reach coroutines.
        """
        publisher = await asyncio.to_thread(
            self.sync.robot,
            fleet,
            robot,
            session_id=session_id,
            cache=cache,
            limits=limits,
            on_error=on_error,
            auto_new_session=auto_new_session,
        )
        return AsyncRobotPublisher(publisher)

    async def subscribe_transitions(
        self,
        fleet: str = "*",
        robot: str = "*",
        *,
        history: bool | int = True,
        maxsize: int = DEFAULT_MAXSIZE,
    ) -> AsyncSubscription[Transition]:
        """Subscribe to transitions; see ``Connection.subscribe_transitions``."""
        sub: AsyncSubscription[Transition] = AsyncSubscription(maxsize)
        declare = self.sync.subscribe_transitions
        return await self._declare(
            sub, lambda: declare(fleet, robot, history=history, handler=sub._from_thread)
        )

    async def subscribe_errors(
        self, fleet: str = "*", robot: str = "*", *, maxsize: int = DEFAULT_MAXSIZE
    ) -> AsyncSubscription[Error]:
        """Subscribe to the service's errors; see ``Connection.subscribe_errors``."""
        sub: AsyncSubscription[Error] = AsyncSubscription(maxsize)
        declare = self.sync.subscribe_errors
        return await self._declare(sub, lambda: declare(fleet, robot, handler=sub._from_thread))

    async def subscribe_events(
        self,
        fleet: str = "*",
        robot: str = "*",
        *,
        history: bool | int = True,
        maxsize: int = DEFAULT_MAXSIZE,
    ) -> AsyncSubscription[Transition | Error]:
        """Subscribe to transitions and errors together; see ``Connection.subscribe_events``."""
        sub: AsyncSubscription[Transition | Error] = AsyncSubscription(maxsize)
        declare = self.sync.subscribe_events
        return await self._declare(
            sub, lambda: declare(fleet, robot, history=history, handler=sub._from_thread)
        )

    async def _declare(
        self, sub: AsyncSubscription[T], declare: Callable[[], Subscription[T]]
    ) -> AsyncSubscription[T]:
        sub._attach(await asyncio.to_thread(declare))
        self._subs.append(sub)
        return sub

    async def state(self, fleet: str, robot: str, timeout_s: float = 2.0) -> SessionState | None:
        """See ``Connection.state``."""
        return await asyncio.to_thread(self.sync.state, fleet, robot, timeout_s)

    async def states(
        self, fleet: str = "*", robot: str = "*", timeout_s: float = 2.0
    ) -> list[SessionState]:
        """See ``Connection.states``."""
        return await asyncio.to_thread(self.sync.states, fleet, robot, timeout_s)

    async def area_graph(self, fleet: str, robot: str, timeout_s: float = 2.0) -> AreaGraph | None:
        """See ``Connection.area_graph``."""
        return await asyncio.to_thread(self.sync.area_graph, fleet, robot, timeout_s)

    async def area_graphs(
        self, fleet: str = "*", robot: str = "*", timeout_s: float = 2.0
    ) -> list[AreaGraph]:
        """See ``Connection.area_graphs``."""
        return await asyncio.to_thread(self.sync.area_graphs, fleet, robot, timeout_s)

    async def fleet_area_graph(
        self, fleet: str, params: FleetParams | None = None, timeout_s: float = 2.0
    ) -> FleetGraph:
        """See ``Connection.fleet_area_graph``."""
        return await asyncio.to_thread(self.sync.fleet_area_graph, fleet, params, timeout_s)

    async def submap(
        self, fleet: str, robot: str, submap_id: int, timeout_s: float = 2.0
    ) -> Submap | None:
        """See ``Connection.submap``."""
        return await asyncio.to_thread(self.sync.submap, fleet, robot, submap_id, timeout_s)

    async def submaps(self, fleet: str, robot: str, timeout_s: float = 2.0) -> list[Submap]:
        """See ``Connection.submaps``."""
        return await asyncio.to_thread(self.sync.submaps, fleet, robot, timeout_s)

    async def health(self, timeout_s: float = 2.0) -> list[Health]:
        """See ``Connection.health``."""
        return await asyncio.to_thread(self.sync.health, timeout_s)

    async def instances(self, timeout_s: float = 1.0) -> list[str]:
        """See ``Connection.instances``."""
        return await asyncio.to_thread(self.sync.instances, timeout_s)

    async def coverage(self, timeout_s: float = 1.0) -> dict[int, tuple[str | None, str | None]]:
        """See ``Connection.coverage``."""
        return await asyncio.to_thread(self.sync.coverage, timeout_s)

    async def wait_for_service(self, timeout_s: float = 10.0) -> bool:
        """See ``Connection.wait_for_service``."""
        return await asyncio.to_thread(self.sync.wait_for_service, timeout_s)

    async def close(self, timeout_s: float = DEFAULT_CLOSE_TIMEOUT_S) -> None:
        """Close the connection and everything declared from it; see ``Connection.close``.

        Its robots end together, with one wait of at most ``timeout_s`` for the service to
        confirm them all, in a worker thread: the event loop goes on meanwhile, and the
        subscriptions, closed after the robots, still deliver what their last frames produce.
        """
        try:
            await asyncio.to_thread(self.sync.close, timeout_s)
        finally:
            subs, self._subs = self._subs, []
            for sub in subs:
                await sub.close()  # wakes its readers

    async def __aenter__(self) -> AsyncConnection:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

"""Closing a connection ends its robots together: one wait for the service, not one per robot.

Real ``lessmap serve`` processes, a real Zenoh router and real sessions on loopback. A ghost
instance token (a token with no service behind it) keeps the robots waiting until their
``timeout_s``, so the time a close takes shows how many waits it made.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import TYPE_CHECKING

import pytest

import lessmap_client
from lessmap_client import Connection, aio
from lessmap_schemas import keys
from tests.client.test_robot_close import features, not_confirmed
from tests.conftest import wait_until

if TYPE_CHECKING:
    from collections.abc import Awaitable, Callable, Iterator

    import zenoh

    from tests.conftest import ServeProcess

pytestmark = pytest.mark.timeout(120)

ROBOTS = 8


@pytest.fixture
def ghost(router: str, client_session: Callable[[str], zenoh.Session]) -> Iterator[str]:
    """An instance token on the router that no service answers for; its name."""
    token = client_session(router).liveliness().declare_token(keys.instance_token("ghost"))
    yield "ghost"
    token.undeclare()


def test_connection_close_confirms_every_robot_in_about_one_wait(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    caplog: pytest.LogCaptureFixture,
) -> None:
    service = serve()
    observer = Connection.from_session(client_session(service.endpoint))
    assert observer.wait_for_service(30.0), service.log()
    one_by_one = lessmap_client.connect(service.endpoint, timeout_s=20.0)
    together = lessmap_client.connect(service.endpoint, timeout_s=20.0)
    robots = 16
    singles = [one_by_one.robot(fleet_name, f"a{i}") for i in range(robots)]
    grouped = [together.robot(fleet_name, f"b{i}") for i in range(robots)]
    assert singles[0].wait_for_service(30.0), service.log()
    assert grouped[0].wait_for_service(30.0), service.log()
    for robot in singles + grouped:
        for seq in range(5):
            robot.publish(features(seq))
    wait_until(
        lambda: sum(s.frames_applied for s in observer.states(fleet_name)) == 2 * robots * 5,
        30.0,
        "every frame applied",
    )
    caplog.set_level(logging.WARNING, logger="lessmap_client")

    started = time.monotonic()
    for robot in singles:
        robot.close()
    sequential_s = time.monotonic() - started
    one_by_one.close()
    started = time.monotonic()
    together.close()
    together_s = time.monotonic() - started

    # Confirmed: the service shows every session closed as soon as close() returns.
    states = {s.robot: s for s in observer.states(fleet_name)}
    assert all(not states[f"b{i}"].open for i in range(robots)), states
    assert all(states[f"b{i}"].frames_applied == 5 for i in range(robots)), states
    assert all(robot.closed for robot in grouped)
    assert together.closed
    assert not_confirmed(caplog) == []
    # Measured: 16 robots one by one 0.36-0.38 s, the connection's close 0.03-0.04 s
    # (its transport included).
    assert together_s < sequential_s / 3, (sequential_s, together_s)
    together.close()  # idempotent, and silent
    assert not_confirmed(caplog) == []
    observer.close()


def test_connection_close_waits_once_for_all_its_robots(
    router: str,
    ghost: str,
    fleet_name: str,
    caplog: pytest.LogCaptureFixture,
) -> None:
    conn = lessmap_client.connect(router, timeout_s=20.0)
    robots = [conn.robot(fleet_name, f"r{i}") for i in range(ROBOTS)]
    sub = conn.subscribe_transitions(fleet_name, history=False)
    wait_until(lambda: all(r.status.owner == ghost for r in robots), 10.0, "the ghost's token")
    for robot in robots:
        robot.publish([1, 2, 3])
    caplog.set_level(logging.WARNING, logger="lessmap_client")

    started = time.monotonic()
    conn.close(timeout_s=1.0)
    elapsed = time.monotonic() - started

    # One wait for the eight robots: one by one, they would take 8 s.
    assert 1.0 <= elapsed < 3.0, elapsed
    [line] = not_confirmed(caplog)
    assert f"end of {ROBOTS} session(s)" in line
    assert "within 1 s" in line
    assert all(robot.closed for robot in robots)
    assert sub.closed
    with pytest.raises(RuntimeError, match="closed"):
        conn.robot(fleet_name, "late")


def test_connection_close_with_timeout_zero_does_not_wait(
    router: str, ghost: str, fleet_name: str
) -> None:
    conn = lessmap_client.connect(router, timeout_s=20.0)
    robots = [conn.robot(fleet_name, f"r{i}") for i in range(ROBOTS)]
    wait_until(lambda: all(r.status.owner == ghost for r in robots), 10.0, "the ghost's token")
    for robot in robots:
        robot.publish([1, 2, 3])
    started = time.monotonic()
    conn.close(timeout_s=0)
    assert time.monotonic() - started < 1.0
    assert all(robot.closed for robot in robots)


async def ticking_while(close: Callable[[], Awaitable[None]]) -> tuple[float, int]:
    """Await ``close()``; return how long it took and how often the loop ticked meanwhile."""
    ticks = 0
    done = asyncio.Event()

    async def tick() -> None:
        nonlocal ticks
        while not done.is_set():
            await asyncio.sleep(0.01)
            ticks += 1

    ticker = asyncio.create_task(tick())
    started = time.monotonic()
    await close()
    elapsed = time.monotonic() - started
    done.set()
    await ticker
    return elapsed, ticks


def test_async_robot_close_returns_at_once_without_a_live_instance(
    router: str, fleet_name: str, caplog: pytest.LogCaptureFixture
) -> None:
    async def run() -> float:
        async with aio.connect(router, timeout_s=20.0) as conn:
            robot = await conn.robot(fleet_name, "alone")
            await robot.publish([1, 2, 3])
            started = time.monotonic()
            await robot.close(timeout_s=10.0)
            elapsed = time.monotonic() - started
            assert robot.sync.closed
            await robot.close(timeout_s=10.0)  # idempotent
            return elapsed

    caplog.set_level(logging.WARNING, logger="lessmap_client")
    assert asyncio.run(run()) < 2.0
    [line] = not_confirmed(caplog)
    assert "no live lessmap instance" in line


def test_async_robot_close_waits_off_the_loop_within_its_timeout(
    router: str, ghost: str, fleet_name: str, caplog: pytest.LogCaptureFixture
) -> None:
    async def run() -> tuple[float, int]:
        async with aio.connect(router, timeout_s=20.0) as conn:
            robot = await conn.robot(fleet_name, "unheard")
            wait_until(lambda: robot.status.owner == ghost, 10.0, "the ghost's token")
            await robot.publish([1, 2, 3])
            return await ticking_while(lambda: robot.close(timeout_s=1.0))

    caplog.set_level(logging.WARNING, logger="lessmap_client")
    elapsed, ticks = asyncio.run(run())
    assert 1.0 <= elapsed < 3.0, elapsed
    assert ticks >= 20, ticks  # the loop ran meanwhile (every 10 ms)
    [line] = not_confirmed(caplog)
    assert "within 1 s" in line


def test_async_connection_close_waits_once_for_all_its_robots(
    router: str, ghost: str, fleet_name: str, caplog: pytest.LogCaptureFixture
) -> None:
    async def run() -> tuple[float, int, list[bool]]:
        conn = aio.AsyncConnection(await asyncio.to_thread(lessmap_client.connect, router))
        robots = [await conn.robot(fleet_name, f"r{i}") for i in range(ROBOTS)]
        wait_until(lambda: all(r.status.owner == ghost for r in robots), 10.0, "the token")
        for robot in robots:
            await robot.publish([1, 2, 3])
        elapsed, ticks = await ticking_while(lambda: conn.close(timeout_s=1.0))
        return elapsed, ticks, [robot.sync.closed for robot in robots]

    caplog.set_level(logging.WARNING, logger="lessmap_client")
    elapsed, ticks, closed = asyncio.run(run())
    assert 1.0 <= elapsed < 3.0, elapsed
    assert ticks >= 20, ticks
    assert all(closed)
    [line] = not_confirmed(caplog)
    assert f"end of {ROBOTS} session(s)" in line

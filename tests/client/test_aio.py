"""The asyncio SDK against a real ``lessmap serve`` on loopback."""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING

import pytest

from lessmap_client import aio
from tests.client.test_sdk_e2e import offline_seqs, two_room_walk

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap_schemas.messages import Transition
    from tests.conftest import ServeProcess

pytestmark = pytest.mark.timeout(180)


async def take(sub: aio.AsyncSubscription[Transition], count: int) -> list[int]:
    seqs: list[int] = []
    async for t in sub:
        seqs.append(t.seq)
        if len(seqs) == count:
            break
    return seqs


async def fleet_app(endpoint: str, fleet: str) -> dict[str, object]:
    walk = two_room_walk(rooms=4)
    async with aio.connect(endpoint, timeout_s=30.0) as conn:
        assert await conn.wait_for_service(20.0)
        first = await conn.subscribe_transitions(fleet, history=False)
        second = await conn.subscribe_transitions(fleet, "walker", history=False)
        async with await conn.robot(fleet, "walker") as robot:
            assert await robot.wait_for_service(20.0)  # the owner took the robot's partition
            for features in walk:
                await robot.publish(features, stamp_s=0.0)
        seqs = await asyncio.wait_for(asyncio.gather(take(first, 3), take(second, 3)), 30.0)
        assert await second.recv(timeout_s=0.3) is None
        states = await conn.states(fleet)
        submap = await conn.submap(fleet, "walker", 1)
        waiting = asyncio.create_task(take(first, 1))  # blocked in `async for` ...
        await asyncio.sleep(0)
    return {
        "seqs": seqs,
        "expected": offline_seqs(walk),
        "states": [(s.robot, s.frames_applied, s.open) for s in states],
        "frames": len(walk),
        "submap": None if submap is None else submap.summary.id,
        "woken": await asyncio.wait_for(waiting, 10.0),  # ... and closing ended it
        "dropped": first.dropped + second.dropped,
    }


def test_async_subscriptions_each_get_every_transition(
    serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    service = serve("--max-batch-frames", "1")
    result = asyncio.run(fleet_app(service.endpoint, fleet_name))
    expected = result["expected"]
    assert result["seqs"] == [expected, expected]
    assert result["states"] == [("walker", result["frames"], False)]
    assert result["submap"] == 1
    assert result["woken"] == []
    assert result["dropped"] == 0

"""A shard's heavy lane: robots whose decisions take long move to a worker of their own.

Real parts: a Zenoh router on loopback, the outbox's session on it, real shards, tables and
worker threads. What is checked: a robot moves whole (mid-session too) and decides exactly
as the paper's loop; the others stay; reads, drains, hand-overs and the stop reach both.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from lessmap.core import PartitionParams
from lessmap.core.segmenter import Method
from lessmap.runtime.heavy import HeavyLane
from lessmap.runtime.metrics import ServiceMetrics
from lessmap.runtime.outbox import EgressPolicy
from lessmap.runtime.sessions import Identity, Segmenting, SessionLimits, SessionTable
from lessmap.runtime.shard import Inbound, Shard, ShardPolicy
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.limits import DEFAULT_LIMITS
from lessmap_schemas.messages import Frame
from tests.service.test_shard_rounds import (
    FLEET,
    RecordingOutbox,
    published_seqs,
    reference_transitions,
    streams,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

# 2 ms of estimated decision: 80,000 cost units, i.e. 8,000 edges. A frame of 200 features
# (19,900 pairs) crosses it at once; the simulated walks stay far below.
HEAVY_MS = 2.0
WIDE = 200


def make_pair(session: zenoh.Session) -> Shard:
    """A shard with its heavy lane, as the service builds them (one outbox)."""
    outbox = RecordingOutbox(
        session,
        ServiceMetrics(),
        instance="inst",
        policy=EgressPolicy(
            transition_cache=4, max_publishers=16, error_rate_per_s=10.0, error_burst=10
        ),
    )

    def shard(index: int, heavy: HeavyLane[Shard] | None) -> Shard:
        table = SessionTable(
            Segmenting(params=PartitionParams.from_profile("laser"), method=Method.PAPER),
            SessionLimits(
                max_sessions=16,
                max_nodes=20_000,
                max_batch_frames=256,
                # Never idle here: on a loaded host the offline reference alone can outlast
                # a minute, and an idle-closed session would leave the hand-over nothing.
                idle_timeout_s=1e6,
                max_pairs_per_frame=200_000,
                max_edges_per_session=1_000_000,
            ),
            identity=Identity(instance="inst"),
        )
        policy = ShardPolicy(
            queue_depth=1 << 16,
            queue_bytes=1 << 26,
            coalesce_after_s=1e9,  # never behind: a decision at every frame, as offline
            heavy_of=None if heavy is not None else 0,
        )
        return Shard(index, table, outbox, limits=DEFAULT_LIMITS, policy=policy, heavy=heavy)

    return shard(0, HeavyLane(shard(1, None), HEAVY_MS))


def frames_of(robot: str, rows: list[list[int]]) -> list[Inbound]:
    return [
        Inbound(
            time.monotonic(),
            keys.frames(FLEET, robot),
            encode(Frame(session="s", seq=seq, stamp_s=float(seq), features=row)),
        )
        for seq, row in enumerate(rows)
    ]


def wait_applied(shard: Shard, robots: dict[str, int]) -> None:
    """Poll both lanes' tables until each robot's last seq is reached (bounded)."""

    def last_seqs(table: SessionTable) -> dict[str, int | None]:
        out = {}
        for robot in robots:
            state = table.state(FLEET, robot)
            out[robot] = None if state is None else state.last_seq
        return out

    deadline = time.monotonic() + 120.0  # a loaded host: heavy decisions take their time
    while True:
        seen: dict[str, int | None] = dict.fromkeys(robots)
        for lane in shard.lanes:
            for robot, seq in lane.read(last_seqs).result(timeout=60.0).items():
                seen[robot] = seq if seq is not None else seen[robot]
        if seen == robots:
            return
        assert time.monotonic() < deadline, f"not applied in time: {seen}"
        time.sleep(0.02)


def where(shard: Shard, robot: str) -> list[int]:
    """Indexes of the lanes whose table holds the robot's open session."""

    def has(table: SessionTable) -> bool:
        state = table.state(FLEET, robot)
        return state is not None and state.open

    return [lane.index for lane in shard.lanes if lane.read(has).result(timeout=60.0)]


def test_a_robot_turning_heavy_moves_whole_and_decides_as_the_paper(
    router: str, client_session: Callable[[str], zenoh.Session]
) -> None:
    shard = make_pair(client_session(router))
    walks = streams()
    # Thirty frames of a walk, then wide frames (half shared with the frame before): the
    # move happens mid-session, with the CovGraph built so far.
    turning = walks["r1"][:30] + [list(range(100 * k, 100 * k + WIDE)) for k in range(40)]
    light = walks["r0"]
    shard.start()
    try:
        assert shard.offer_many(frames_of("r1", turning[:30]) + frames_of("r0", light)) == []
        wait_applied(shard, {"r1": 29, "r0": len(light) - 1})
        assert where(shard, "r1") == [0]  # light so far
        assert shard.offer_many(frames_of("r1", turning)[30:]) == []
        wait_applied(shard, {"r1": len(turning) - 1})
        assert where(shard, "r1") == [1]
        assert where(shard, "r0") == [0]
        heavy_lane = shard.lanes[1]
        # Every transition of both, decision for decision the paper's loop.
        assert published_seqs(shard, "r0") == reference_transitions(light)
        expected = reference_transitions(turning)
        assert any(seq >= 30 for seq in expected), "the wide frames make transitions"
        assert published_seqs(shard, "r1") == expected
        # The hand-over and the drain reach the heavy lane's session too.
        assert shard.drain(lambda _f, _r: True).result(timeout=10.0) is None
        handed = shard.hand_over_sessions(lambda _f, robot: robot == "r1", time.monotonic())
        assert handed.result(timeout=10.0) == 1
        assert heavy_lane.open_sessions == 0
        assert shard.open_sessions == 1
    finally:
        shard.stop(10.0)
    assert not any(t.name.startswith("lessmap-heavy-") for t in threading.enumerate())


def test_a_robot_heavy_from_its_first_frame_never_touches_the_shards_table(
    router: str, client_session: Callable[[str], zenoh.Session]
) -> None:
    shard = make_pair(client_session(router))
    wide = [list(range(100 * k, 100 * k + WIDE)) for k in range(20)]
    shard.start()
    try:
        assert shard.offer_many(frames_of("cam", wide)) == []
        wait_applied(shard, {"cam": len(wide) - 1})
        assert where(shard, "cam") == [1]
        assert shard.read(lambda table: table.robots()).result(timeout=10.0) == []
        assert published_seqs(shard, "cam") == reference_transitions(wide)
    finally:
        shard.stop(10.0)
    closed = [
        state.robot
        for outcome in shard._outbox.published  # type: ignore[attr-defined]
        for state, _cause in outcome.closed
    ]
    assert closed == ["cam"]  # closed once, by the heavy lane's worker at the stop

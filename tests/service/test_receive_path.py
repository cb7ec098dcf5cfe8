"""The receive path: frames channels swept into the shards' bounded queues, latency histograms.

Real parts: a Zenoh router on loopback, the receiving session and a robot's session joined
to it, real shards (their workers not started, so the test reads what was queued).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest
from prometheus_client import CollectorRegistry, Histogram, generate_latest

from lessmap.core import PartitionParams
from lessmap.runtime.metrics import BatchHistogram, ServiceMetrics
from lessmap.runtime.outbox import EgressPolicy, Outbox
from lessmap.runtime.receiver import EVERY_PARTITION, Receiver
from lessmap.runtime.sessions import Identity, Segmenting, SessionLimits, SessionTable
from lessmap.runtime.shard import CATCHUP_DONE, PROBE, Inbound, Shard, ShardPolicy
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.limits import DEFAULT_LIMITS
from lessmap_schemas.messages import Frame
from lessmap_schemas.partition import partition_of
from tests.conftest import metric_value, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

FLEET = "fleet"
BUCKETS = (0.001, 0.005, 0.01, 0.25, 1.0)


def exposition(registry: CollectorRegistry, name: str) -> list[str]:
    lines = generate_latest(registry).decode().splitlines()
    return [line for line in lines if line.startswith(f"{name}_") and "_created" not in line]


@pytest.mark.parametrize("batch", [False, True], ids=["one-by-one", "batch"])
def test_batch_histogram_exposes_what_a_prometheus_histogram_does(batch: bool) -> None:
    values = [0.0, 0.001, 0.0011, 0.3, 1.0, 7.5, 0.004, 0.25]
    ours, theirs = CollectorRegistry(), CollectorRegistry()
    mine = BatchHistogram("lat_seconds", "latency", buckets=BUCKETS, registry=ours)
    reference = Histogram("lat_seconds", "latency", buckets=BUCKETS, registry=theirs)
    if batch:
        mine.observe_many(values[:3])
        mine.observe_many(values[3:])
    else:
        for value in values:
            mine.observe(value)
    for value in values:
        reference.observe(value)
    assert exposition(ours, "lat_seconds") == exposition(theirs, "lat_seconds")


def make_shard(session: zenoh.Session, metrics: ServiceMetrics, queue_depth: int) -> Shard:
    outbox = Outbox(
        session,
        metrics,
        instance="inst",
        policy=EgressPolicy(
            transition_cache=4,
            max_publishers=8,
            error_rate_per_s=10.0,
            error_burst=10,
        ),
    )
    table = SessionTable(
        Segmenting(params=PartitionParams.from_profile("laser")),
        SessionLimits(max_sessions=8, max_nodes=1000, max_batch_frames=8, idle_timeout_s=60.0),
        identity=Identity(instance="inst"),
    )
    return Shard(
        0,
        table,
        outbox,
        limits=DEFAULT_LIMITS,
        policy=ShardPolicy(queue_depth=queue_depth, queue_bytes=1 << 20),
    )


def item(robot: str, seq: int, kind: int = 0) -> Inbound:
    frame = Frame(session="s", seq=seq, stamp_s=float(seq), features=[1, 2])
    return Inbound(0.0, keys.frames(FLEET, robot), encode(frame), kind)


def test_offer_many_keeps_the_bounds_of_offer(
    router: str, client_session: Callable[[str], zenoh.Session]
) -> None:
    shard = make_shard(client_session(router), ServiceMetrics(), queue_depth=8)
    # One robot may hold a quarter of the depth: 2 of its 3 are taken, in order.
    batch = [item("a", 0), item("b", 0), item("a", 1), item("a", 2), item("b", 1)]
    refused = shard.offer_many(batch)
    assert refused == [batch[3]]
    assert shard.depth() == 4
    # The depth: robots c, d take 2 each, then nothing more fits, but a query's end does.
    more = [item(r, s) for r in "cdef" for s in range(2)]
    assert shard.offer_many(more) == more[4:]
    assert shard.depth() == 8
    done = Inbound(0.0, keys.frames(FLEET, "a"), b"s", CATCHUP_DONE)
    assert shard.offer_many([done]) == []
    assert shard.offer(item("g", 0)) is False
    assert list(shard._inbound.queue)[:4] == [batch[0], batch[1], batch[2], batch[4]]


def wait_matched(publisher: zenoh.Publisher) -> None:
    def matched() -> bool:
        status: Any = publisher.matching_status  # a MatchingStatus (the stubs say bool)
        return bool(status.matching)

    wait_until(matched, 20.0, "the subscriber to match")


@pytest.mark.parametrize("subscription", ["partitions", "all"])
def test_receiver_sweeps_samples_into_the_shard_and_reports_what_it_refuses(
    router: str, client_session: Callable[[str], zenoh.Session], subscription: str
) -> None:
    service_session, robot_session = client_session(router), client_session(router)
    metrics = ServiceMetrics()
    shard = make_shard(service_session, metrics, queue_depth=8)
    mine = partition_of(FLEET, "mine")
    other = next(r for r in (f"r{i}" for i in range(1000)) if partition_of(FLEET, r) != mine)
    receiver = Receiver(
        [shard], metrics, max_payload_bytes=1000, queue_depth=64, owned=lambda p: p == mine
    )
    if subscription == "all":
        subs = {
            EVERY_PARTITION: service_session.declare_subscriber(
                keys.frames_of_every_partition(), receiver.channel()
            )
        }
    else:
        subs = {
            p: service_session.declare_subscriber(keys.frames_of_partition(p), receiver.channel())
            for p in (mine, partition_of(FLEET, other))
        }
    receiver.watch(subs)
    receiver.start()
    try:
        own = robot_session.declare_publisher(keys.frames(FLEET, "mine"))
        foreign = robot_session.declare_publisher(keys.frames(FLEET, other))
        wait_matched(own)
        wait_matched(foreign)
        for seq in range(5):
            own.put(item("mine", seq).payload)
        own.put(b"\x00" * 2000)  # over max_payload_bytes: refused unread
        for seq in range(3):
            foreign.put(item(other, seq).payload)
        hostile = ["\u00b2", "1" * 5000, "abc"]  # no partition: digits int() refuses, or none
        if subscription == "all":  # only the one subscription to every partition sees them
            for chunk in hostile:
                robot_session.put(keys.frames(FLEET, "mine").rsplit("/", 1)[0] + "/" + chunk, b"x")

        def text() -> str:
            return generate_latest(metrics.registry).decode()

        wait_until(
            lambda: (
                metric_value(text(), "lessmap_frames_received_total") == 6
                and metric_value(text(), "lessmap_frames_foreign_total")
                == 3 + (len(hostile) if subscription == "all" else 0)
            ),
            20.0,
            "every sample swept",
            text,
        )
    finally:
        receiver.stop()
    # A robot may hold 8 / 4 = 2 messages: 2 queued, 3 refused as queue full.
    assert shard.depth() == 2
    notes = list(shard._inbound.notes)
    assert [code for _key, code, _detail in notes] == [ErrorCode.LIMIT_EXCEEDED] * 4
    assert sum("exceeds limit=1000" in detail for _k, _c, detail in notes) == 1
    assert sum("queue full" in detail for _k, _c, detail in notes) == 3


def test_the_last_sweep_takes_what_an_undeclared_channel_holds(
    router: str, client_session: Callable[[str], zenoh.Session]
) -> None:
    service_session, robot_session = client_session(router), client_session(router)
    metrics = ServiceMetrics()
    shard = make_shard(service_session, metrics, queue_depth=64)
    mine = partition_of(FLEET, "mine")
    receiver = Receiver(
        [shard], metrics, max_payload_bytes=1000, queue_depth=64, owned=lambda p: p == mine
    )
    sub = service_session.declare_subscriber(keys.frames_of_partition(mine), receiver.channel())
    # A second subscriber on the same session sees each sample when the channel gets it.
    seen: list[int] = []
    witness = service_session.declare_subscriber(
        keys.frames_of_partition(mine), lambda _sample: seen.append(1)
    )
    receiver.watch({mine: sub})  # not started: only the final sweep runs
    publisher = robot_session.declare_publisher(keys.frames(FLEET, "mine"))
    wait_matched(publisher)
    for seq in range(4):
        publisher.put(item("mine", seq).payload)
    wait_until(lambda: len(seen) == 4, 20.0, "the frames in the channel")
    witness.undeclare()
    sub.undeclare()
    receiver.stop()
    assert shard.depth() == 4
    assert [i.payload for i in shard._inbound.queue] == [item("mine", s).payload for s in range(4)]


@pytest.mark.parametrize("subscription", ["partitions", "all"])
def test_frames_of_a_partition_on_its_way_are_held_then_handed_on_first_as_probes(
    router: str, client_session: Callable[[str], zenoh.Session], subscription: str
) -> None:
    service_session, robot_session = client_session(router), client_session(router)
    metrics = ServiceMetrics()
    shard = make_shard(service_session, metrics, queue_depth=64)
    coming = partition_of(FLEET, "coming")
    owned: set[int] = set()
    receiver = Receiver(
        [shard], metrics, max_payload_bytes=1000, queue_depth=64, owned=owned.__contains__
    )
    key = keys.frames_of_every_partition() if subscription == "all" else None
    sub = service_session.declare_subscriber(
        key or keys.frames_of_partition(coming), receiver.channel()
    )
    receiver.hold([coming])
    receiver.watch({EVERY_PARTITION if key else coming: sub})
    publisher = robot_session.declare_publisher(keys.frames(FLEET, "coming"))
    wait_matched(publisher)
    for seq in range(3):
        publisher.put(item("coming", seq).payload)
    hostile = ["\u00b2", "1" * 5000, "abc"]  # no partition, even while one is held
    if key is not None:
        for chunk in hostile:
            robot_session.put(keys.frames(FLEET, "coming").rsplit("/", 1)[0] + "/" + chunk, b"x")

    def text() -> str:
        return generate_latest(metrics.registry).decode()

    def swept() -> bool:
        receiver.sweep()
        foreign = metric_value(text(), "lessmap_frames_foreign_total")
        return len(receiver._held) == 3 and foreign == (len(hostile) if key else 0)

    wait_until(swept, 20.0, "three held, the rest foreign", text)
    assert shard.depth() == 0  # nothing reaches a shard before the partition is taken
    assert metric_value(text(), "lessmap_frames_received_total") == 3

    assert receiver.admit([coming], owned.add) == 3
    assert owned == {coming}
    publisher.put(item("coming", 3).payload)  # live from now on, after the held ones
    wait_until(lambda: (receiver.sweep(), shard.depth())[1] == 4, 20.0, "the live frame")
    queued = list(shard._inbound.queue)
    assert [i.payload for i in queued] == [item("coming", s).payload for s in range(4)]
    assert [i.kind for i in queued] == [PROBE, PROBE, PROBE, 0]
    assert metric_value(text(), "lessmap_frames_received_total") == 4
    sub.undeclare()
    receiver.stop()


def test_a_probe_reply_goes_behind_the_live_frames_already_received(
    router: str, client_session: Callable[[str], zenoh.Session]
) -> None:
    # A take-over's probe asks a robot's cache for its newest frame while the robot still
    # sends: the copy of frame 1 comes after the live frames 0 and 1, which wait in the
    # channel for the next sweep. Handed to the shard at once, the copy came first, was
    # applied beyond a gap, and the live frame 0 then counted as late and was never applied.
    service_session, robot_session = client_session(router), client_session(router)
    metrics = ServiceMetrics()
    shard = make_shard(service_session, metrics, queue_depth=64)
    mine = partition_of(FLEET, "mine")
    receiver = Receiver(
        [shard], metrics, max_payload_bytes=1000, queue_depth=64, owned=lambda p: p == mine
    )
    sub = service_session.declare_subscriber(keys.frames_of_every_partition(), receiver.channel())
    receiver.watch({EVERY_PARTITION: sub})
    # A second subscriber of the same session sees each sample when the receiver's does.
    witness = service_session.declare_subscriber(
        keys.frames_of_every_partition(), receiver.channel()
    )
    publisher = robot_session.declare_publisher(keys.frames(FLEET, "mine"))
    wait_matched(publisher)
    for seq in range(2):
        publisher.put(item("mine", seq).payload)
    seen = 0

    def both_seen() -> bool:
        nonlocal seen
        while witness.handler.try_recv() is not None:
            seen += 1
        return seen == 2

    wait_until(both_seen, 20.0, "the live frames in the channel (not swept yet)")
    receiver.probe(item("mine", 1, PROBE))
    assert shard.depth() == 0  # the reply waits for the sweep
    wait_until(lambda: (receiver.sweep(), shard.depth())[1] == 3, 20.0, "the frames and the copy")
    queued = list(shard._inbound.queue)
    assert [i.payload for i in queued] == [item("mine", s).payload for s in (0, 1, 1)]
    assert [i.kind for i in queued] == [0, 0, PROBE]
    witness.undeclare()
    sub.undeclare()
    receiver.stop()

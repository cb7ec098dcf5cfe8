"""The in-process fake bus, used the way an SDK user tests a fleet app with it."""

from __future__ import annotations

import asyncio
import threading

import pytest

from lessmap_client import Connection, aio
from lessmap_client.testing import FakeBus, key_matches, make_error, make_state, make_transition
from lessmap_schemas import AreaGraph, Transition, keys
from lessmap_schemas.errors import ErrorCode, InvalidNameError, WireError
from lessmap_schemas.messages import AreaNode, Passage
from lessmap_schemas.partition import PARTITIONS
from tests.conftest import wait_until


def test_every_subscription_gets_every_transition_once() -> None:
    bus = FakeBus()
    with bus.connect() as conn:
        first = conn.subscribe_transitions("warehouse")
        second = conn.subscribe_transitions("warehouse", "amr-7")
        other_fleet = conn.subscribe_transitions("yard")
        handled: list[Transition] = []
        done = threading.Event()

        def handler(t: Transition) -> None:
            handled.append(t)
            if len(handled) == 5:
                done.set()

        conn.subscribe_transitions(handler=handler)
        sent = [make_transition("warehouse", "amr-7", closed_id=i) for i in range(5)]
        for t in sent:
            bus.publish_transition(t)
        bus.publish_transition(sent[2])  # a repeat (fail-over): dropped by every subscription
        assert [first.try_recv() for _ in range(5)] == sent
        assert [second.recv(timeout_s=1.0) for _ in range(5)] == sent
        assert first.try_recv() is None
        assert second.try_recv() is None  # the repeat was read and skipped
        assert (first.duplicates, second.duplicates) == (1, 1)
        assert other_fleet.try_recv() is None
        assert done.wait(5.0)
        assert handled == sent


def test_history_is_replayed_to_late_subscribers_only_when_asked() -> None:
    bus = FakeBus(history=2)
    for i in range(3):
        bus.publish_transition(make_transition("f", "r", closed_id=i))
    with bus.connect() as conn:
        late = conn.subscribe_transitions("f", history=True)
        live = conn.subscribe_transitions("f", history=False)
        assert [t.closed.id for t in (late.try_recv(), late.try_recv())] == [1, 2]  # type: ignore[union-attr]
        assert late.try_recv() is None
        assert live.try_recv() is None


def test_the_fake_records_what_robots_publish() -> None:
    bus = FakeBus()
    with bus.connect() as conn:
        assert conn.wait_for_service(0.1)
        with conn.robot("warehouse", "amr-7", session_id="boot-1") as robot:
            assert robot.publish([3, 1, 2], stamp_s=1.0, pose=(0.0, 1.0, 0.5)) == 0
            assert robot.publish([4], stamp_s=2.0) == 1
            with pytest.raises(WireError, match="max_features_per_frame"):
                robot.publish(range(5000))
        other = conn.robot("warehouse", "amr-8")  # closed with the connection
        other.publish([9])
    frames = bus.frames("warehouse", "amr-7")
    assert [(f.seq, f.features, f.session) for f in frames] == [
        (0, [3, 1, 2], "boot-1"),
        (1, [4], "boot-1"),
    ]
    assert frames[0].pose == (0.0, 1.0, 0.5)
    ends = bus.session_ends("warehouse", "amr-7")
    assert [(e.session, e.last_seq) for e in ends] == [("boot-1", 1)]
    assert [e.last_seq for e in bus.session_ends(robot="amr-8")] == [0]
    assert [(s.robot, type(s.message).__name__) for s in bus.sent] == [
        ("amr-7", "Frame"),
        ("amr-7", "Frame"),
        ("amr-7", "SessionEnd"),
        ("amr-8", "Frame"),
        ("amr-8", "SessionEnd"),
    ]
    with pytest.raises(InvalidNameError):
        FakeBus().connect().robot("warehouse", "no/slash")


def test_queries_answer_what_was_stored() -> None:
    bus = FakeBus()
    bus.set_state(make_state("f", "a", frames_applied=30, transitions=2))
    bus.set_state(make_state("f", "b", open=False))
    bus.set_state(make_state("g", "c"))
    with bus.connect() as conn:
        assert sorted(s.robot for s in conn.states("f")) == ["a", "b"]
        assert len(conn.states()) == 3
        state = conn.state("f", "a")
        assert state is not None
        assert (state.frames_applied, state.transitions, state.current_submap.id) == (30, 2, 2)
        assert conn.state("f", "nobody") is None
        assert conn.health() == []
        assert conn.submaps("f", "a") == []
    bus.instances = []
    with bus.connect() as conn:
        assert not conn.wait_for_service(0.2)


def test_errors_and_garbage_reach_the_app_as_a_real_service_would_send_them() -> None:
    bus = FakeBus()
    with bus.connect() as conn:
        errors = conn.subscribe_errors("f")
        events = conn.subscribe_events("f", "r")
        bus.publish_error(make_error("f", "r", ErrorCode.SEQ_GAP, "frames 3..4 missing"))
        bus.put(keys.transitions("f", "r"), b"\xc1 not msgpack")
        bus.publish_transition(make_transition("f", "r"))
        error = errors.try_recv()
        assert error is not None
        assert (error.code, error.detail) == (ErrorCode.SEQ_GAP, "frames 3..4 missing")
        got = [events.try_recv(), events.try_recv(), events.try_recv()]
        assert [type(e).__name__ for e in got] == ["Error", "Transition", "NoneType"]
        assert events.undecodable == 1


def test_a_full_queue_drops_new_events_and_counts_them() -> None:
    bus = FakeBus()
    with bus.connect() as conn:
        sub = conn.subscribe_transitions(maxsize=3)
        for i in range(10):
            bus.publish_transition(make_transition("f", "r", closed_id=i))
        assert sub.dropped == 7
        assert [t.closed.id for t in iter(sub.try_recv, None)] == [0, 1, 2]


def test_closing_ends_iteration_and_the_connection() -> None:
    bus = FakeBus()
    conn = bus.connect()
    sub = conn.subscribe_transitions()
    seen: list[int] = []
    reader = threading.Thread(target=lambda: seen.extend(t.closed.id for t in sub))
    reader.start()
    bus.publish_transition(make_transition("f", "r", closed_id=4))
    wait_until(lambda: seen == [4], 5.0, "the reader to get the transition")
    conn.close()
    reader.join(5.0)
    assert not reader.is_alive()
    assert sub.closed
    bus.publish_transition(make_transition("f", "r", closed_id=5))  # nobody listens anymore
    assert seen == [4]
    with pytest.raises(RuntimeError, match="closed"):
        conn.subscribe_transitions()
    with pytest.raises(RuntimeError, match="handler"):
        Connection(bus.connect().transport).subscribe_transitions(handler=print).try_recv()


def test_the_fake_works_with_asyncio() -> None:
    async def app(bus: FakeBus) -> list[int]:
        async with aio.AsyncConnection(bus.connect()) as conn:
            sub = await conn.subscribe_transitions("f")
            robot = await conn.robot("f", "r")
            await robot.publish([1, 2])
            bus.publish_transition(make_transition("f", "r", closed_id=0))
            bus.publish_transition(make_transition("f", "r", closed_id=1))
            got = [t.closed.id async for t in _take(sub, 2)]
            assert await conn.states("f") == []
            return got

    bus = FakeBus()
    assert asyncio.run(app(bus)) == [0, 1]
    assert [f.features for f in bus.frames("f", "r")] == [[1, 2]]
    assert len(bus.session_ends("f", "r")) == 1  # closing the connection closed the robot


async def _take(sub: aio.AsyncSubscription[Transition], n: int):  # type: ignore[no-untyped-def]
    for _ in range(n):
        event = await sub.recv(timeout_s=5.0)
        assert event is not None
        yield event


@pytest.mark.parametrize(
    ("pattern", "key", "matches"),
    [
        ("lessmap/v4/*/*/transitions", "lessmap/v4/f/r/transitions", True),
        ("lessmap/v4/f/*/transitions", "lessmap/v4/g/r/transitions", False),
        ("lessmap/v4/**", "lessmap/v4/f/r/errors", True),
        ("lessmap/v4/*/*/errors", "lessmap/v4/@/errors/i", False),
        ("lessmap/v4/**", "lessmap/v4/@/errors/i", False),
        ("lessmap/v4/**", "lessmap/v4/@/instances/i", False),
        ("lessmap/v4/f/r/submaps/*", "lessmap/v4/f/r/submaps/3", True),
        ("lessmap/v4/*/*/frames/23", "lessmap/v4/warehouse/amr-7/frames/23", True),
        ("lessmap/v4/*/*/frames/22", "lessmap/v4/warehouse/amr-7/frames/23", False),
        ("lessmap/v4/*/*/frames/*", "lessmap/v4/warehouse/amr-7/frames/23", True),
        ("lessmap/v1/*/*/transitions", "lessmap/v4/f/r/transitions", False),
    ],
)
def test_key_matching_follows_zenoh(pattern: str, key: str, matches: bool) -> None:
    assert key_matches(pattern, key) is matches


def test_async_robot_follows_its_errors_and_new_sessions() -> None:
    from lessmap_client import aio
    from lessmap_client.testing import FakeBus, make_error
    from lessmap_schemas.errors import ErrorCode

    async def scenario() -> tuple[int, str, str, int]:
        bus = FakeBus()
        seen: list[object] = []
        conn = aio.AsyncConnection(bus.connect())
        robot = await conn.robot("f", "r", on_error=seen.append)
        first = robot.session_id
        await robot.publish([1, 2, 3])
        bus.publish_error(
            make_error("f", "r", ErrorCode.SESSION_CLOSED, session=robot.session_id, seq=0)
        )
        robot.sync.flush_errors(2.0)
        await robot.publish([4, 5])  # auto_new_session: a new id, seq 0
        second = robot.session_id
        count = robot.status.count(ErrorCode.SESSION_CLOSED)
        await conn.close()
        return len(seen), first, second, count

    errors, first, second, count = asyncio.run(scenario())
    assert errors == 1
    assert count == 1
    assert first != second


def test_the_fake_routes_partitioned_frames_keys_and_counts_misrouted_ones() -> None:
    from lessmap_schemas.codec import encode
    from lessmap_schemas.messages import Frame
    from lessmap_schemas.partition import partition_of

    bus = FakeBus()
    p = partition_of("warehouse", "amr-7")
    payload = encode(Frame(session="s", seq=0, stamp_s=0.0, features=[1]))
    bus.put(f"lessmap/v4/warehouse/amr-7/frames/{p}", payload)
    other = (p + 1) % PARTITIONS
    bus.put(f"lessmap/v4/warehouse/amr-7/frames/{other}", payload)  # another partition
    bus.put("lessmap/v4/warehouse/amr-7/frames", payload)  # v1 shape: no partition chunk
    assert [f.seq for f in bus.frames("warehouse", "amr-7")] == [0]
    assert bus.misrouted_sent == 2
    with bus.connect() as conn, conn.robot("warehouse", "amr-7") as robot:
        robot.publish([2])
    assert len(bus.frames("warehouse", "amr-7")) == 2
    assert bus.misrouted_sent == 2


def test_the_fake_emits_epoch_stamped_events_and_the_sdk_fences_them() -> None:
    from lessmap_schemas.partition import partition_of

    bus = FakeBus()
    t = make_transition("f", "r")
    assert (t.partition, t.epoch, t.v) == (partition_of("f", "r"), 1, 4)
    assert make_state("f", "r").epoch == 1
    assert make_error("f", "r").epoch == 1
    assert make_error(None, None, ErrorCode.MALFORMED).epoch is None
    with pytest.raises(ValueError, match="partition"):
        bus.publish_transition(t.model_copy(update={"partition": (t.partition + 1) % PARTITIONS}))
    with bus.connect() as conn:
        events = conn.subscribe_events("f")
        bus.publish_transition(make_transition("f", "r", closed_id=0, epoch=7))
        bus.publish_transition(make_transition("f", "r", closed_id=1, epoch=6))  # deposed owner
        bus.publish_error(make_error("f", "r", epoch=6))
        bus.publish_error(make_error("f", "r", detail="unattributed", epoch=None))
        bus.publish_transition(make_transition("f", "other", closed_id=0, epoch=1))
        bus.publish_transition(make_transition("f", "r", closed_id=0, epoch=8))  # recomputed
        bus.publish_transition(make_transition("f", "r", closed_id=1, epoch=8))
        got = []
        while (event := events.try_recv()) is not None:
            got.append(event)
        assert [(e.type, e.robot, e.epoch) for e in got] == [
            ("Transition", "r", 7),
            ("Error", "r", None),
            ("Transition", "other", 1),
            ("Transition", "r", 8),
        ]
        assert (events.dropped_stale, events.duplicates) == (2, 1)


def test_states_keep_the_highest_epoch_per_robot() -> None:
    bus = FakeBus()
    # The fake keeps one answer per key; two owners' answers need two keys' worth of robots.
    bus.set_state(make_state("f", "a", frames_applied=5, epoch=3))
    with bus.connect() as conn:
        assert [s.epoch for s in conn.states("f")] == [3]
    from lessmap_client.fencing import current_states

    old = make_state("f", "a", frames_applied=50, epoch=3, instance="old")
    new = make_state("f", "a", frames_applied=10, epoch=4, instance="new")
    more = make_state("f", "a", frames_applied=11, epoch=4, instance="more")
    other = make_state("f", "b", epoch=1)
    assert current_states([old, other, new, more]) == [more, other]
    assert current_states([new, old]) == [new]


def test_instances_are_tokens_the_robots_follow() -> None:
    from lessmap_schemas.partition import assignment, owner_and_standby

    bus = FakeBus(instances=[])
    with bus.connect() as conn, conn.robot("f", "r") as robot:

        def owner() -> str | None:  # read afresh each time
            return robot.status.owner

        assert owner() is None
        assert not robot.wait_for_service(0.05)
        assert not conn.wait_for_service(0.05)
        assert conn.coverage() == {p: (None, None) for p in range(PARTITIONS)}
        bus.add_instance("a")
        assert owner() == "a"
        assert robot.wait_for_service(0.0)
        bus.instances = ["a", "b", "c"]
        expected = owner_and_standby(robot.partition, ["a", "b", "c"])
        assert owner() == expected[0]
        assert conn.coverage() == assignment(["c", "b", "a"])
        assert conn.instances() == ["a", "b", "c"]
        for name in ["a", "b", "c"]:
            bus.remove_instance(name)
        assert owner() is None
        assert bus.instances == ()
        with pytest.raises(InvalidNameError):
            bus.add_instance("bad/name")


def test_async_coverage_and_robot_service() -> None:
    async def scenario() -> tuple[bool, bool, str | None, int]:
        bus = FakeBus(instances=[])
        async with aio.AsyncConnection(bus.connect()) as conn:
            robot = await conn.robot("f", "r")
            before = await robot.wait_for_service(0.05)
            bus.add_instance("only")
            after = await robot.wait_for_service(1.0)
            coverage = await conn.coverage()
            owners = {owner for owner, _ in coverage.values()}
            sub = await conn.subscribe_transitions("f")
            bus.publish_transition(make_transition("f", "r", closed_id=0, epoch=2))
            bus.publish_transition(make_transition("f", "r", closed_id=1, epoch=1))
            assert await sub.recv(5.0) is not None
            assert await sub.recv(0.2) is None
            await robot.close()
            return before, after, owners.pop() if len(owners) == 1 else None, sub.dropped_stale

    assert asyncio.run(scenario()) == (False, True, "only", 1)


def test_a_robot_waits_until_its_owner_lists_its_partition() -> None:
    from lessmap_schemas.messages import Health

    def health(partitions: list[int]) -> Health:
        return Health(
            instance="a",
            version="0.3.0",
            sessions=0,
            uptime_s=1.0,
            frames_applied=0,
            partitions=partitions,
            standby=[],
            queue_depth=0,
            lag_s=0.0,
        )

    bus = FakeBus(instances=["a"])
    with bus.connect() as conn, conn.robot("f", "r") as robot:
        assert robot.status.owner == "a"
        assert robot.wait_for_service(0.0)  # an owner that answers no Health: its token counts
        bus.set_health(health([p for p in range(PARTITIONS) if p != robot.partition]))
        assert not robot.wait_for_service(0.3)  # owner, but it has not taken the partition
        bus.set_health(health(list(range(PARTITIONS))))
        assert robot.wait_for_service(0.3)


def _area_graph(robot: str, epoch: int, frames: int, instance: str = "i") -> AreaGraph:
    return AreaGraph(
        fleet="f",
        robot=robot,
        session="s",
        instance=instance,
        epoch=epoch,
        method="areas",
        areas=[
            AreaNode(id=0, frames=frames, visits=2, first_seq=0, last_seq=frames, features=[1]),
            AreaNode(id=1, frames=3, visits=1, first_seq=4, last_seq=6, features=[2, 3]),
        ],
        passages=[Passage(a=0, b=1, a_to_b=1, b_to_a=1, boundary_features=[(2, 2)])],
    )


def test_area_graph_queries_answer_what_was_stored_and_keep_the_highest_epoch() -> None:
    bus = FakeBus()
    bus.set_area_graph(_area_graph("a", epoch=2, frames=10))
    bus.set_area_graph(_area_graph("b", epoch=1, frames=5))
    with bus.connect() as conn:
        graph = conn.area_graph("f", "a")
        assert graph is not None
        assert [(n.id, n.visits) for n in graph.areas] == [(0, 2), (1, 1)]
        assert graph.passages[0].boundary_features == [(2, 2)]
        assert sorted(g.robot for g in conn.area_graphs("f")) == ["a", "b"]
        assert conn.area_graph("f", "nobody") is None
    from lessmap_client.fencing import current_area_graphs

    old = _area_graph("a", epoch=3, frames=50, instance="old")
    new = _area_graph("a", epoch=4, frames=10, instance="new")
    more = _area_graph("a", epoch=4, frames=11, instance="more")
    assert current_area_graphs([old, new, more]) == [more]

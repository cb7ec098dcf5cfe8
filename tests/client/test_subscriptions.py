"""Connections and subscriptions against a real ``lessmap serve`` on loopback."""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import pytest

import lessmap_client
from lessmap_client import connect
from lessmap_schemas.errors import ErrorCode
from tests.client.test_sdk_e2e import offline_seqs, two_room_walk
from tests.conftest import ServeProcess, free_port, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap_client import Connection, Subscription
    from lessmap_schemas.messages import Transition

pytestmark = pytest.mark.timeout(180)

WALK = two_room_walk(rooms=6)  # five doors: five transitions


def publish_walk(conn: Connection, fleet: str, robot: str = "walker") -> str:
    with conn.robot(fleet, robot) as publisher:
        assert publisher.wait_for_service(20.0)  # the owner has taken the robot's partition
        for features in WALK:
            publisher.publish(features, stamp_s=0.0)
        return publisher.session_id


def read(sub: Subscription[Transition], count: int, timeout_s: float = 20.0) -> list[int]:
    seqs: list[int] = []
    for _ in range(count):
        t = sub.recv(timeout_s)
        assert t is not None, f"got only {seqs}"
        seqs.append(t.seq)
    return seqs


def test_every_subscription_and_every_handler_gets_every_transition(
    serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    expected = offline_seqs(WALK)
    assert len(expected) == 5
    service = serve("--max-batch-frames", "1")
    handled: dict[str, list[int]] = {"a": [], "b": []}
    done = {name: threading.Event() for name in handled}

    def handler(name: str) -> Callable[[Transition], None]:
        def on_transition(t: Transition) -> None:
            handled[name].append(t.seq)
            if len(handled[name]) == len(expected):
                done[name].set()

        return on_transition

    with connect(service.endpoint, timeout_s=30.0) as conn:
        assert conn.wait_for_service(20.0), service.log()
        fleet_sub = conn.subscribe_transitions(fleet_name, history=False)
        robot_sub = conn.subscribe_transitions(fleet_name, "walker", history=False)
        everything = conn.subscribe_transitions()
        conn.subscribe_transitions(fleet_name, handler=handler("a"))
        conn.subscribe_transitions(fleet_name, handler=handler("b"))
        session_id = publish_walk(conn, fleet_name)
        assert read(fleet_sub, 5) == expected
        assert read(robot_sub, 5) == expected
        assert read(everything, 5) == expected
        assert done["a"].wait(20.0), handled
        assert done["b"].wait(20.0), handled
        assert handled == {"a": expected, "b": expected}
        for sub in (fleet_sub, robot_sub, everything):
            assert sub.try_recv() is None
            assert sub.dropped == 0

        # A late subscriber recovers the history from the service's cache, once each.
        with conn.subscribe_transitions(fleet_name, history=True) as late:
            recovered = [late.recv(20.0) for _ in expected]
            assert [t.seq for t in recovered if t is not None] == expected
            assert {(t.robot, t.session) for t in recovered if t} == {("walker", session_id)}
            assert late.recv(0.5) is None

        # Queries, all from the connection.
        state = conn.state(fleet_name, "walker")
        assert state is not None
        assert (state.open, state.frames_applied, state.transitions) == (False, len(WALK), 5)
        assert [s.robot for s in conn.states(fleet_name)] == ["walker"]
        submaps = conn.submaps(fleet_name, "walker")
        assert [s.summary.id for s in submaps] == [0, 1, 2, 3, 4, 5]
        one = conn.submap(fleet_name, "walker", 2)
        assert one is not None
        assert one.summary == submaps[2].summary
        assert conn.submap(fleet_name, "walker", 99) is None
        assert [h.instance for h in conn.health()] == [service.instance]
        assert conn.instances() == [service.instance]
    assert conn.closed
    assert fleet_sub.closed


def test_a_slow_reader_loses_new_events_counted_and_keeps_the_first(
    serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    expected = offline_seqs(WALK)
    service = serve("--max-batch-frames", "1")
    with connect(service.endpoint, timeout_s=30.0) as conn:
        assert conn.wait_for_service(20.0), service.log()
        small = conn.subscribe_transitions(fleet_name, history=False, maxsize=2)
        roomy = conn.subscribe_transitions(fleet_name, history=False)
        publish_walk(conn, fleet_name)
        assert read(roomy, 5) == expected  # everything was delivered to the connection
        wait_until(lambda: small.dropped == 3, 20.0, "the small queue to drop three")
        assert read(small, 2) == expected[:2]
        assert small.try_recv() is None


def test_errors_subscription_reports_a_seq_gap(
    serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    service = serve()
    with (
        connect(service.endpoint, timeout_s=30.0) as conn,
        conn.subscribe_errors(fleet_name) as errors,
    ):
        assert conn.wait_for_service(20.0), service.log()
        transitions = conn.subscribe_transitions(fleet_name)
        robot = conn.robot(fleet_name, "gappy")
        robot.publish([1, 2])
        robot.publish([2, 3], seq=5)  # frames 1..4 never sent
        error = errors.recv(20.0)
        assert error is not None, service.log()
        assert (error.code, error.robot, error.seq) == (ErrorCode.SEQ_GAP, "gappy", 5)
        assert transitions.try_recv() is None  # errors stay out of transition subscriptions
    assert robot.closed  # closing the connection ended the robot's session


def test_closing_the_connection_ends_robot_sessions_and_wakes_readers(
    serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    service = serve()
    conn = connect([service.endpoint], timeout_s=30.0)
    assert conn.wait_for_service(20.0), service.log()
    robot = conn.robot(fleet_name, "r")
    robot.publish([1, 2, 3])
    sub = conn.subscribe_transitions(fleet_name)
    results: list[object] = []
    reader = threading.Thread(target=lambda: results.append([t for t in sub]))
    reader.start()
    conn.close()
    reader.join(10.0)
    assert not reader.is_alive()
    assert results == [[]]
    conn.close()  # idempotent
    with pytest.raises(RuntimeError, match="closed"):
        conn.states()
    with connect(service.endpoint, timeout_s=30.0) as other:
        wait_until(
            lambda: (s := other.state(fleet_name, "r")) is not None and not s.open,
            20.0,
            "the session to be ended by the SessionEnd",
        )


def test_connect_without_a_router_fails_within_the_timeout() -> None:
    with pytest.raises(ConnectionError, match="no Zenoh router"):
        connect(f"tcp/127.0.0.1:{free_port()}", timeout_s=0.5)
    assert lessmap_client.DEFAULT_ENDPOINT == "tcp/127.0.0.1:7447"

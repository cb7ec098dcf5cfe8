"""Epochs and partitions in the SDK over a real Zenoh router: fencing by epoch, the current state of
several replies, partition owners from the instances' liveliness tokens, ``lessmap status``.

The test plays the service with a Zenoh session of its own (tokens, queryables, forged
puts), so each case is exact; the SDK is the one a user installs.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from typing import TYPE_CHECKING

import pytest

from lessmap_client import FleetClient, connect
from lessmap_client.testing import make_error, make_state, make_transition
from lessmap_schemas import keys
from lessmap_schemas.codec import encode, encoding
from lessmap_schemas.messages import Health
from lessmap_schemas.partition import PARTITIONS, assignment, owner_and_standby, partition_of
from tests.conftest import REPO, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

    from lessmap_schemas.messages import Error, SessionState, Transition

pytestmark = pytest.mark.timeout(120)


def put(session: zenoh.Session, message: Transition | Error) -> None:
    key = (
        keys.transitions(message.fleet, message.robot)
        if message.type == "Transition"
        else keys.errors(message.fleet or "*", message.robot or "*")
    )
    session.put(key, encode(message), encoding=encoding(message))


def until_subscribed(session: zenoh.Session, recv: Callable[[float], object], fleet: str) -> None:
    """Put probe transitions of another robot until the subscriber's ``recv`` gets one."""
    probe_id = iter(range(10_000))

    def delivered() -> bool:
        put(session, make_transition(fleet, "probe", closed_id=next(probe_id), epoch=1))
        return recv(0.2) is not None

    wait_until(delivered, 20.0, "the subscription to be declared")
    while recv(0.3) is not None:  # probes still on the way
        pass


def test_a_forged_transition_with_a_lower_epoch_is_dropped(
    router: str, client_session: Callable[[str], zenoh.Session], fleet_name: str
) -> None:
    service = client_session(router)
    with connect(router) as conn, FleetClient(fleet_name, session=conn, history=0) as fleet:
        until_subscribed(service, fleet.next_event, fleet_name)
        put(service, make_transition(fleet_name, "r1", closed_id=0, epoch=5, instance="new"))
        first = fleet.next_transition(10.0)
        assert first is not None
        assert (first.robot, first.closed.id, first.epoch) == ("r1", 0, 5)
        # A deposed owner's late transition: a new identity, but an older epoch.
        put(service, make_transition(fleet_name, "r1", closed_id=1, epoch=3, instance="old"))
        # Another robot's epochs are its own; the same epoch again is current.
        put(service, make_transition(fleet_name, "r2", closed_id=0, epoch=1))
        put(service, make_transition(fleet_name, "r1", closed_id=1, epoch=5, instance="new"))
        got = [fleet.next_transition(10.0) for _ in range(2)]
        assert [(t.robot, t.closed.id, t.epoch, t.instance) for t in got if t] == [
            ("r2", 0, 1, "fake"),
            ("r1", 1, 5, "new"),
        ]
        assert fleet.next_transition(0.5) is None
        assert fleet.dropped_stale == 1
        # A recomputed transition (a hand-over: higher epoch, same identity) is a repeat.
        put(service, make_transition(fleet_name, "r1", closed_id=1, epoch=9, instance="next"))
        put(service, make_transition(fleet_name, "r1", closed_id=2, epoch=7, instance="new"))
        put(service, make_transition(fleet_name, "r1", closed_id=2, epoch=9, instance="next"))
        last = fleet.next_transition(10.0)
        assert last is not None
        assert (last.closed.id, last.epoch) == (2, 9)
        assert fleet.next_transition(0.5) is None
        assert (fleet.dropped_stale, fleet.duplicates) == (2, 1)


def test_errors_are_fenced_unless_their_epoch_is_null(
    router: str, client_session: Callable[[str], zenoh.Session], fleet_name: str
) -> None:
    service = client_session(router)
    with connect(router) as conn:
        events = conn.subscribe_events(fleet_name, history=False)
        until_subscribed(service, events.recv, fleet_name)
        put(service, make_transition(fleet_name, "r1", epoch=10))
        first = events.recv(10.0)  # errors come on another key: no order across keys
        assert first is not None
        assert first.type == "Transition"
        put(service, make_error(fleet_name, "r1", "SEQ_GAP", "old owner", epoch=9))
        put(service, make_error(fleet_name, "r1", "SEQ_GAP", "no epoch", epoch=None))
        put(service, make_error(fleet_name, "r1", "SEQ_GAP", "current owner", epoch=10))
        got = [events.recv(10.0), events.recv(10.0)]
        assert [e.detail for e in got if e is not None and e.type == "Error"] == [
            "no epoch",
            "current owner",
        ]
        assert events.recv(0.5) is None
        assert events.dropped_stale == 1


def serve_states(session: zenoh.Session, states: list[SessionState]) -> list[object]:
    """Declare one queryable per reply, as several instances would answer."""
    queryables: list[object] = []
    for state in states:
        key, payload = keys.state(state.fleet, state.robot), encode(state)

        def reply(query: zenoh.Query, key: str = key, payload: bytes = payload) -> None:
            query.reply(key, payload)

        queryables.append(session.declare_queryable(key, reply))
    return queryables


def test_of_several_state_replies_the_highest_epoch_is_current(
    router: str, client_session: Callable[[str], zenoh.Session], fleet_name: str
) -> None:
    old_owner, service = client_session(router), client_session(router)
    deposed = make_state(fleet_name, "r1", frames_applied=90, epoch=4, instance="old")
    current = make_state(fleet_name, "r1", frames_applied=40, epoch=8, instance="new")
    tie_low = make_state(fleet_name, "r2", frames_applied=5, epoch=8, instance="a")
    tie_high = make_state(fleet_name, "r2", frames_applied=6, epoch=8, instance="b")
    handles = [
        *serve_states(old_owner, [deposed]),
        *serve_states(service, [current, tie_low, tie_high]),
    ]
    with connect(router) as conn:
        wait_until(lambda: len(conn.states(fleet_name, timeout_s=1.0)) == 2, 20.0, "replies")
        states = {s.robot: s for s in conn.states(fleet_name)}
        assert (states["r1"].instance, states["r1"].epoch) == ("new", 8)
        assert states["r2"].instance == "b"
        one = conn.state(fleet_name, "r1")
        assert one is not None
        assert one.instance == "new"
        with conn.robot(fleet_name, "r1", session_id="s0") as robot:
            mine = robot.state()
            assert mine is not None
            assert mine.instance == "new"
    del handles


def test_a_robot_knows_whether_its_partition_has_an_owner(
    router: str,
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    caplog: pytest.LogCaptureFixture,
) -> None:
    service = client_session(router)
    caplog.set_level(logging.INFO, logger="lessmap_client.robot")
    with connect(router) as conn, conn.robot(fleet_name, "r1") as robot:
        p = partition_of(fleet_name, "r1")

        def owner() -> str | None:  # read afresh each time
            return robot.status.owner

        assert robot.partition == robot.status.partition == p
        assert owner() is None
        assert not robot.wait_for_service(0.5)
        assert conn.coverage() == {q: (None, None) for q in range(PARTITIONS)}

        x = service.liveliness().declare_token(keys.instance_token("x"))
        wait_until(lambda: owner() == "x", 20.0, "x to own the robot's partition")
        # Served means the owner's frames subscription matches too: until then, no.
        assert not robot.wait_for_service(0.5)
        frames_sub = service.declare_subscriber(keys.frames_of_partition(p), lambda _s: None)
        assert robot.wait_for_service(20.0)
        assert owner() == "x"
        y = service.liveliness().declare_token(keys.instance_token("y"))
        expected = owner_and_standby(p, ["x", "y"])
        wait_until(lambda: conn.instances() == ["x", "y"], 20.0, "both tokens")
        assert conn.coverage() == assignment(["x", "y"])
        assert conn.coverage()[p] == expected
        wait_until(lambda: owner() == expected[0], 20.0, "the owner among x and y")

        caplog.clear()
        x.undeclare()
        y.undeclare()
        wait_until(lambda: owner() is None, 20.0, "the tokens to go")
        assert not robot.wait_for_service(0.2)
        robot.publish([1, 2, 3])  # an unserved robot may publish: the cache keeps the frame
        z = service.liveliness().declare_token(keys.instance_token("z"))
        wait_until(lambda: owner() == "z", 20.0, "a new owner")
        assert robot.wait_for_service(0.0)
        assert robot.flush_errors(5.0)
        records = [r for r in caplog.records if r.name == "lessmap_client.robot"]
        warnings = [r for r in records if r.levelno == logging.WARNING]
        infos = [r for r in records if r.levelno == logging.INFO]
        assert len(warnings) == 1, [r.getMessage() for r in records]
        assert f"owns partition {p}" in warnings[0].getMessage()
        assert len(infos) == 1, [r.getMessage() for r in records]
        assert "served again, by z" in infos[0].getMessage()
        z.undeclare()
        frames_sub.undeclare()


def test_a_robot_drops_a_deposed_owners_error(
    router: str, client_session: Callable[[str], zenoh.Session], fleet_name: str
) -> None:
    service = client_session(router)
    with connect(router) as conn, conn.robot(fleet_name, "r1", auto_new_session=False) as robot:
        session_id = robot.session_id

        def report(detail: str, epoch: int, code: str = "SEQ_GAP") -> None:
            put(
                service, make_error(fleet_name, "r1", code, detail, session=session_id, epoch=epoch)
            )

        def probed() -> bool:
            report("probe", 20)
            return robot.status.count("SEQ_GAP") > 0

        wait_until(probed, 20.0, "a report")
        report("closed by a deposed owner", 19, "SESSION_CLOSED")
        report("current owner", 20)

        def last_detail() -> str | None:
            error = robot.status.last_error
            return None if error is None else error.detail

        wait_until(lambda: last_detail() == "current owner", 20.0, "the last report")
        status = robot.status
        assert status.reports_stale == 1
        assert not status.closed_by_service
        assert status.count("SESSION_CLOSED") == 0


# -- lessmap status ----------------------------------------------------------------------------


def run_status(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lessmap", "status", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
        check=False,
    )


def health(instance: str, partitions: list[int], standby: list[int]) -> Health:
    return Health(
        instance=instance,
        version="0.3.0",
        sessions=2,
        uptime_s=12.5,
        frames_applied=100,
        partitions=partitions,
        standby=standby,
        queue_depth=3,
        lag_s=0.25,
    )


def test_lessmap_status_flags_an_owner_that_has_not_taken_its_partition(
    router: str, client_session: Callable[[str], zenoh.Session]
) -> None:
    service = client_session(router)
    table = assignment(["a", "b"])
    owns = {n: [p for p, (o, _) in table.items() if o == n] for n in "ab"}
    shadows = {n: [p for p, (_, s) in table.items() if s == n] for n in "ab"}
    lagging = owns["b"][0]  # b should own it, a still serves it
    answers = {
        "a": health("a", sorted([*owns["a"], lagging]), shadows["a"]),
        "b": health("b", [p for p in owns["b"] if p != lagging], shadows["b"]),
    }
    tokens = [service.liveliness().declare_token(keys.instance_token(n)) for n in "ab"]
    handles = []
    for name, answer in answers.items():
        payload = encode(answer)

        def reply(query: zenoh.Query, name: str = name, payload: bytes = payload) -> None:
            query.reply(keys.health(name), payload)

        handles.append(service.declare_queryable(keys.health(name), reply))

    result = run_status("-e", router, "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    rows = {entry["instance"]: entry for entry in report["instances"]}
    assert sorted(rows) == ["a", "b"]
    assert rows["a"]["owned"] == len(owns["a"]) + 1
    assert rows["b"]["standby_count"] == len(shadows["b"])
    assert (rows["a"]["queue_depth"], rows["a"]["lag_s"], rows["a"]["version"]) == (
        3,
        0.25,
        "0.3.0",
    )
    assert report["disagreements"] == 1
    assert not report["ok"]
    flagged = [entry for entry in report["partitions"] if entry["flags"]]
    assert [entry["partition"] for entry in flagged] == [lagging]
    assert flagged[0]["owner"] == "b"
    assert flagged[0]["served_by"] == ["a"]
    assert "owner b has not taken it yet" in flagged[0]["flags"]
    assert all(
        (entry["owner"], entry["standby"]) == table[entry["partition"]]
        for entry in report["partitions"]
    )

    text = run_status("-e", router)
    assert text.returncode == 0, text.stderr
    assert "owner b has not taken it yet; a still serves it" in text.stdout
    assert f"{PARTITIONS - 1} of {PARTITIONS} partitions served" in text.stdout
    for token in tokens:
        token.undeclare()
    del handles


def test_lessmap_status_without_an_instance_is_one_line_and_exit_1(router: str) -> None:
    result = run_status("-e", router, "--timeout", "0.5")
    assert result.returncode == 1
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1
    assert result.stderr.startswith("lessmap status: no lessmap instance answered at")


@pytest.mark.parametrize(
    ("args", "says", "code"),
    [
        # Out of range: the command line is wrong (exit 2); no router: the command failed.
        (["--timeout", "0"], "--timeout: must be a positive number", 2),
        (["--timeout", "nan"], "--timeout: must be a positive number", 2),
        (["--connect-timeout", "-1"], "--connect-timeout: must be a positive number", 2),
        (["--connect-timeout", "0.3", "-e", "tcp/127.0.0.1:1"], "no Zenoh router answered", 1),
    ],
)
def test_lessmap_status_bad_input_is_one_line(args: list[str], says: str, code: int) -> None:
    result = run_status(*args)
    assert result.returncode == code
    assert "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1, result.stderr
    assert says in result.stderr

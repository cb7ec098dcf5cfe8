"""mTLS + access control end to end: what each role may do, and what never gets through.

Each refusal is checked next to a positive control on the same path (the same sessions, a
moment later), so a test fails if the path was broken for another reason: "nothing arrived"
only counts when something legitimate did arrive.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap.security.certs import make_site
from lessmap_client import connect
from lessmap_client.session import open_session
from lessmap_schemas import encode, encoding, keys
from lessmap_schemas.codec import decode
from lessmap_schemas.messages import (
    Frame,
    SessionEnd,
    SessionState,
    SubmapSummary,
    Transition,
)
from lessmap_schemas.partition import partition_of
from tests.conftest import ServeProcess, wait_until
from tests.security.conftest import crossed

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from lessmap_client import Connection, RobotPublisher
    from tests.security.conftest import SecureSite

pytestmark = pytest.mark.timeout(120)

#: How long a refused message gets to show up anyway, after the positive control arrived.
QUIET_S = 1.0


def walk_two_rooms(robot: RobotPublisher, frames: int = 40) -> None:
    """Publish frames that see one room, then a disjoint one: one transition."""
    assert robot.wait_for_service(20.0), "the robot's partition is not served"
    for i in range(frames):
        base = 0 if i < frames // 2 else 1000
        robot.publish(range(base, base + 12), stamp_s=0.1 * i)


def forged_transition(fleet: str, robot: str) -> Transition:
    closed = SubmapSummary(id=0, first_seq=0, last_seq=9, frame_count=10, features=[1, 2])
    opened = SubmapSummary(id=1, first_seq=10, last_seq=10, frame_count=1, features=[3])
    return Transition(
        fleet=fleet,
        robot=robot,
        session="forged",
        incarnation=0,
        seq=10,
        boundary_seq=10,
        stamp_s=1.0,
        reason="DISCONNECTED",
        ncut=None,
        lambda2=None,
        closed=closed,
        opened=opened,
        boundary_features=[],
        area=1,
        left_area=0,
        revisit=False,
        batch_frames=1,
        instance="evil",
        partition=partition_of(fleet, robot),
        epoch=2**40,  # above any real epoch: a client would prefer it
    )


def collect(session: zenoh.Session, key: str) -> tuple[zenoh.Subscriber[None], list[bytes]]:
    """Subscribe with a plain Zenoh subscriber; return it and the list it fills."""
    got: list[bytes] = []
    sub = session.declare_subscriber(key, lambda sample: got.append(sample.payload.to_bytes()))
    return sub, got


def answer_with(payload: bytes) -> Callable[[zenoh.Query], None]:
    """A queryable's callback that replies ``payload`` on the key asked."""

    def answer(query: zenoh.Query) -> None:
        query.reply(query.key_expr, payload)

    return answer


def test_a_robot_and_an_app_of_one_fleet_work_end_to_end(
    site: SecureSite, service: ServeProcess, connect_as: Callable[..., Connection]
) -> None:
    app = connect_as("app")
    assert app.wait_for_service(20.0), service.log()
    events = app.subscribe_transitions(site.fleet)
    robot = connect_as("robot").robot(site.fleet, "amr-1")
    assert robot.wait_for_service(10.0)
    # The robot follows the instances' tokens (a liveliness subscriber): it sees its owner.
    assert robot.status.owner == service.instance
    walk_two_rooms(robot)

    transition = events.recv(timeout_s=15.0)
    assert transition is not None, service.log()
    assert (transition.fleet, transition.robot) == (site.fleet, "amr-1")
    assert transition.instance == service.instance
    wait_until(
        lambda: (s := app.state(site.fleet, "amr-1")) is not None and s.frames_applied == 40,
        10.0,
        "the state query to see all 40 frames",
    )
    assert [h.instance for h in app.health()] == [service.instance]
    graph = app.area_graph(site.fleet, "amr-1")  # the areas key passes the access control
    assert graph is not None
    assert [a.id for a in graph.areas] == [0, 1]
    # The robot follows its own session through the SDK (errors subscription, state query).
    state = robot.state()
    assert state is not None
    assert state.transitions == 1


def test_a_robot_of_another_fleet_cannot_feed_this_fleet(
    site: SecureSite,
    service: ServeProcess,
    connect_as: Callable[..., Connection],
    session_as: Callable[..., zenoh.Session],
) -> None:
    app = connect_as("app")
    assert app.wait_for_service(20.0), service.log()
    intruder = session_as("robot", site.other)  # robot.G, a valid certificate of this site
    frame = Frame(session="s-intrude", seq=0, stamp_s=0.0, features=[1, 2, 3])
    for seq in range(5):
        payload = encode(frame.model_copy(update={"seq": seq}))
        intruder.put(keys.frames(site.fleet, "victim"), payload, encoding=encoding(frame))
    # Positive control: the same session may feed its own fleet, and the service applies it
    # (once the service's subscription has reached this fresh session).
    crossed(intruder, keys.frames(site.other, "own"), "the service's subscription")
    for seq in range(5):
        payload = encode(frame.model_copy(update={"seq": seq}))
        intruder.put(keys.frames(site.other, "own"), payload, encoding=encoding(frame))
    own = connect_as("app", site.other)
    wait_until(
        lambda: (s := own.state(site.other, "own")) is not None and s.frames_applied == 5,
        15.0,
        "robot G's own frames to be applied",
    )
    time.sleep(QUIET_S)
    assert app.state(site.fleet, "victim") is None
    assert app.states(site.fleet) == []


def test_only_the_fleets_robots_may_end_or_replace_a_robots_session(
    site: SecureSite,
    service: ServeProcess,
    connect_as: Callable[..., Connection],
    session_as: Callable[..., zenoh.Session],
) -> None:
    # The rule (schemas/README.md §6): a SessionEnd or a frame with a new session id is
    # obeyed from whoever may put on the robot's frames key; access control limits that key
    # to the robot's fleet. Robot G's SessionEnd and new-session frame for F's robot are
    # never applied, and F's session goes on.
    robots = connect_as("robot")
    app = connect_as("app")
    assert app.wait_for_service(20.0), service.log()
    victim = robots.robot(site.fleet, "victim")
    assert victim.wait_for_service(20.0), service.log()
    for seq in range(5):
        victim.publish([seq, seq + 1, 100])
    wait_until(
        lambda: (s := app.state(site.fleet, "victim")) is not None and s.frames_applied == 5,
        15.0,
        "the victim's first frames",
    )
    intruder = session_as("robot", site.other)
    end = SessionEnd(session=victim.session_id, last_seq=4, stamp_s=0.0)
    intruder.put(keys.frames(site.fleet, "victim"), encode(end), encoding=encoding(end))
    takeover = Frame(session="s-takeover", seq=0, stamp_s=0.0, features=[1])
    intruder.put(keys.frames(site.fleet, "victim"), encode(takeover), encoding=encoding(takeover))
    time.sleep(QUIET_S)
    for seq in range(5, 10):
        victim.publish([seq, seq + 1, 100])
    wait_until(
        lambda: (s := app.state(site.fleet, "victim")) is not None and s.frames_applied == 10,
        15.0,
        "the victim's later frames, in the same session",
    )
    state = app.state(site.fleet, "victim")
    assert state is not None
    assert state.open
    assert state.session == victim.session_id
    assert victim.status.closed_by_service is False


def test_a_robot_cannot_forge_transitions(
    site: SecureSite,
    service: ServeProcess,
    connect_as: Callable[..., Connection],
    session_as: Callable[..., zenoh.Session],
) -> None:
    app = connect_as("app")
    assert app.wait_for_service(20.0), service.log()
    raw = session_as("app")
    sub, received = collect(raw, keys.transitions(site.fleet, "*"))
    events = app.subscribe_transitions(site.fleet)

    forger = session_as("robot")  # robot.F: a robot of this very fleet
    fake = forged_transition(site.fleet, "amr-1")
    forger.put(keys.transitions(site.fleet, "amr-1"), encode(fake), encoding=encoding(fake))
    # Positive control: a real transition of the same robot arrives on the same subscribers.
    robot = connect_as("robot").robot(site.fleet, "amr-1")
    walk_two_rooms(robot)
    real = events.recv(timeout_s=15.0)
    assert real is not None, service.log()
    assert real.instance == service.instance
    wait_until(lambda: bool(received), 5.0, "the real transition on the raw subscriber")
    time.sleep(QUIET_S)
    sub.undeclare()
    assert [decode(p, Transition).instance for p in received] == [service.instance]
    assert events.try_recv() is None


def test_an_app_of_another_fleet_can_neither_query_nor_follow_this_fleet(
    site: SecureSite,
    service: ServeProcess,
    connect_as: Callable[..., Connection],
    session_as: Callable[..., zenoh.Session],
) -> None:
    spy = connect_as("app", site.other)  # app.G
    assert spy.wait_for_service(20.0), service.log()  # the service's liveliness: allowed
    spy_events = spy.subscribe_transitions(site.fleet)
    spy_raw = session_as("app", site.other)
    sub, spied = collect(spy_raw, keys.transitions("*", "*"))  # every fleet at once
    app = connect_as("app")
    events = app.subscribe_transitions(site.fleet)

    robot = connect_as("robot").robot(site.fleet, "amr-1")
    walk_two_rooms(robot)
    assert events.recv(timeout_s=15.0) is not None, service.log()  # positive control
    assert app.state(site.fleet, "amr-1") is not None
    time.sleep(QUIET_S)
    assert spy_events.try_recv() is None
    assert spied == []
    sub.undeclare()
    assert spy.state(site.fleet, "amr-1") is None
    assert spy.states(site.fleet) == []
    assert spy.submaps(site.fleet, "amr-1") == []
    assert app.area_graph(site.fleet, "amr-1") is not None  # positive control
    assert spy.area_graph(site.fleet, "amr-1") is None
    assert list(spy_raw.get(keys.state("*", "*"), timeout=1.0)) == []
    assert list(spy_raw.get(keys.areas("*", "*"), timeout=1.0)) == []


def test_only_the_service_may_announce_an_instance_or_answer_for_it(
    site: SecureSite,
    router: zenoh.Session,
    connect_as: Callable[..., Connection],
    session_as: Callable[..., zenoh.Session],
) -> None:
    # No service runs. A robot and an app try to pass for one.
    declared: list[object] = []  # a dropped token or queryable is undeclared: keep them
    for role in ("robot", "app"):
        impostor = session_as(role)
        declared.append(impostor.liveliness().declare_token(keys.instance_token(f"evil-{role}")))
        fake = SessionState(
            fleet=site.fleet,
            robot="amr-1",
            session="forged",
            incarnation=0,
            instance="evil",
            epoch=2**40,
            open=True,
            last_seq=99,
            frames_applied=100,
            frames_duplicate=0,
            frames_missing=0,
            frames_rejected=0,
            transitions=0,
            method="paper",
            current_area=0,
            current_submap=SubmapSummary(
                id=0, first_seq=0, last_seq=99, frame_count=100, features=[1]
            ),
            closed_submaps=[],
            nodes=1,
            edges=0,
        )
        payload = encode(fake)
        declared.append(
            impostor.declare_queryable(
                keys.state(site.fleet, "amr-1"),
                answer_with(payload),
            )
        )
    app = connect_as("app")
    assert not app.wait_for_service(2.0)
    assert app.instances() == []
    assert app.state(site.fleet, "amr-1") is None

    # Positive control: the same token and queryable from the service's identity are seen.
    real = session_as("service")
    declared.append(real.liveliness().declare_token(keys.instance_token("control")))
    declared.append(real.declare_queryable(keys.state(site.fleet, "amr-2"), answer_with(payload)))
    assert app.wait_for_service(5.0)
    assert app.instances() == ["control"]
    state = app.state(site.fleet, "amr-2")
    assert state is not None
    assert state.instance == "evil"  # the control's payload: it is the path that is checked


def test_a_client_without_a_certificate_of_this_site_cannot_connect(
    site: SecureSite, router: zenoh.Session, tmp_path: Path
) -> None:
    folder = site.site.folder
    no_cert = tmp_path / "no-cert.json5"
    no_cert.write_text(
        '{ transport: { link: { tls: { root_ca_certificate: "%s" } } } }' % (folder / "ca.pem")
    )
    with pytest.raises(ConnectionError):
        connect(site.endpoint, config_file=str(no_cert), timeout_s=2.0)
    # A certificate from another CA, with the right common name, is refused too.
    stranger = make_site(tmp_path / "elsewhere", [site.fleet], endpoint=site.endpoint)
    mixed = tmp_path / "stranger.json5"
    mixed.write_text(
        stranger.robots[site.fleet]
        .read_text()
        .replace(f"{stranger.folder}/ca.pem", f"{folder}/ca.pem")
    )
    with pytest.raises(ConnectionError):
        connect(site.endpoint, config_file=str(mixed), timeout_s=2.0)
    # Plain TCP to the TLS port gets nowhere.
    with pytest.raises(ConnectionError):
        open_session([site.endpoint.replace("tls/", "tcp/")], timeout_s=2.0)
    # Positive control: the site's own robot certificate connects.
    with connect(site.endpoint, config_file=str(site.site.robots[site.fleet]), timeout_s=10.0):
        pass

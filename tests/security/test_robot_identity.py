"""Per-robot identities (``lessmap certs --robot F/R``) end to end, over real mTLS on loopback.

Fleet F has robots r1 and r2, each with a certificate of its own (CN ``robot.F/r1``,
``robot.F/r2``) and no fleet-wide ``robot.F``; fleet G keeps a fleet-wide identity. Each
refusal sits next to a positive control on the same session: the same message, put by the
same certificate on its own robot's key, does arrive.
"""

from __future__ import annotations

import datetime
import time
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.security import pki
from lessmap.security.siteconfig import client_config, render, robot_name
from lessmap_client.session import open_session
from lessmap_schemas import encode, encoding, keys
from lessmap_schemas.messages import Frame, SessionEnd
from tests.conftest import wait_until
from tests.security.conftest import crossed, secure_site
from tests.security.test_mtls_e2e import collect, walk_two_rooms
from tests.security.test_partition_acl import Collector, answer_with, put_until, replies

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import zenoh

    from lessmap_client import Connection
    from tests.conftest import ServeProcess
    from tests.security.conftest import SecureSite

pytestmark = pytest.mark.timeout(120)

#: How long a refused message gets to show up anyway, after the positive control arrived.
QUIET_S = 1.0


@pytest.fixture
def site(tmp_path: Path, fleet_name: str) -> SecureSite:
    """Fleet F with per-robot identities for r1 and r2; fleet G with a fleet-wide one."""
    return secure_site(tmp_path / "site", fleet_name, robots=("r1", "r2"))


def wait_applied(app: Connection, fleet: str, robot: str, count: int, what: str) -> None:
    """Wait until the service reports ``count`` frames applied in the robot's session."""

    def applied() -> bool:
        state = app.state(fleet, robot)
        return state is not None and state.frames_applied == count

    wait_until(applied, 15.0, what)


def test_each_robot_runs_its_session_with_its_own_certificate(
    site: SecureSite, service: ServeProcess, connect_as: Callable[..., Connection]
) -> None:
    assert f"robot.{site.fleet}" not in {p.stem for p in site.site.folder.glob("*.pem")}
    app = connect_as("app")
    assert app.wait_for_service(20.0), service.log()
    events = app.subscribe_transitions(site.fleet)
    for name in ("r1", "r2"):
        robot = connect_as("robot", f"{site.fleet}/{name}").robot(site.fleet, name)
        assert robot.wait_for_service(20.0), service.log()
        assert robot.status.owner == service.instance
        walk_two_rooms(robot)
        transition = events.recv(timeout_s=15.0)
        assert transition is not None, service.log()
        assert (transition.fleet, transition.robot) == (site.fleet, name)
        wait_applied(app, site.fleet, name, 40, f"{name}'s 40 frames")
        state = robot.state()  # the robot follows its own session: its state key passes
        assert state is not None
        assert state.transitions == 1


def test_a_robot_can_neither_feed_nor_end_another_robots_session(
    site: SecureSite,
    service: ServeProcess,
    connect_as: Callable[..., Connection],
    session_as: Callable[..., zenoh.Session],
) -> None:
    app = connect_as("app")
    assert app.wait_for_service(20.0), service.log()
    bus = session_as("service")  # what reaches the service's side on r2's key
    sub, on_r2_key = collect(bus, keys.frames(site.fleet, "r2"))
    victim = connect_as("robot", f"{site.fleet}/r2").robot(site.fleet, "r2")
    assert victim.wait_for_service(20.0), service.log()
    for seq in range(5):
        victim.publish([seq, seq + 1, 100])
    wait_applied(app, site.fleet, "r2", 5, "r2's first frames")

    intruder = session_as("robot", f"{site.fleet}/r1")  # robot.F/r1, valid on this site
    # The service's subscription has reached the intruder: a refused put is the router's doing.
    crossed(intruder, keys.frames(site.fleet, "r2"), "the service's subscription (r2's key)")
    forged = [
        Frame(session=victim.session_id, seq=5, stamp_s=0.5, features=[9999]),  # r2's session
        Frame(session="s-takeover", seq=0, stamp_s=0.0, features=[1]),  # a new session
        SessionEnd(session=victim.session_id, last_seq=4, stamp_s=0.0),
    ]
    for message in forged:
        intruder.put(keys.frames(site.fleet, "r2"), encode(message), encoding=encoding(message))
    # Positive control: the same session puts the same kinds of message on its own key.
    own = [Frame(session="s-own", seq=seq, stamp_s=0.1 * seq, features=[seq]) for seq in range(3)]
    for message in [*own, SessionEnd(session="s-own", last_seq=2, stamp_s=1.0)]:
        intruder.put(keys.frames(site.fleet, "r1"), encode(message), encoding=encoding(message))
    wait_until(
        lambda: (s := app.state(site.fleet, "r1")) is not None and not s.open,
        15.0,
        "r1's own frames and SessionEnd to be applied",
    )
    time.sleep(QUIET_S)
    for seq in range(5, 10):
        victim.publish([seq, seq + 1, 100])
    wait_applied(app, site.fleet, "r2", 10, "r2's later frames, in the same session")
    state = app.state(site.fleet, "r2")
    assert state is not None
    assert (state.open, state.session) == (True, victim.session_id)
    assert (state.frames_duplicate, state.frames_rejected) == (0, 0)
    assert victim.status.closed_by_service is False
    # Nothing of the intruder's on r2's key, while r2's own frames were all there.
    sub.undeclare()
    assert len(on_r2_key) == 10
    assert not {encode(m) for m in forged} & set(on_r2_key)


@pytest.mark.usefixtures("router")
def test_a_robot_cannot_answer_or_announce_for_another_robots_cache(
    site: SecureSite, session_as: Callable[..., zenoh.Session]
) -> None:
    # What the service's catch-up asks (the robot's AdvancedPublisher cache, under @adv) and
    # the liveliness token a publisher declares there: r1 may not speak for r2.
    r1, r2 = session_as("robot", f"{site.fleet}/r1"), session_as("robot", f"{site.fleet}/r2")
    service = session_as("service")
    declared: list[object] = []  # a dropped queryable or token is undeclared: keep them
    for robot, session in (("r1", r1), ("r2", r2)):
        cache = f"{keys.frames(site.fleet, robot)}/@adv/pub/x"
        declared.append(session.declare_queryable(cache, answer_with(cache, robot.encode())))
        declared.append(session.liveliness().declare_token(f"{cache}/token"))
        forged = f"{keys.frames(site.fleet, 'r2' if robot == 'r1' else 'r1')}/@adv/pub/forged"
        declared.append(session.declare_queryable(forged, answer_with(forged, b"forged")))
        declared.append(session.liveliness().declare_token(f"{forged}/token"))

    def answers(robot: str) -> set[bytes]:
        return replies(service, f"{keys.frames(site.fleet, robot)}/@adv/**", 1.0)

    def tokens(robot: str) -> set[str]:
        found = service.liveliness().get(f"{keys.frames(site.fleet, robot)}/@adv/**", timeout=1.0)
        return {str(reply.ok.key_expr) for reply in found if reply.ok is not None}

    wait_until(lambda: answers("r1") == {b"r1"} and answers("r2") == {b"r2"}, 20.0, "caches")
    time.sleep(QUIET_S)
    assert answers("r1") == {b"r1"}
    assert answers("r2") == {b"r2"}
    assert tokens("r2") == {f"{keys.frames(site.fleet, 'r2')}/@adv/pub/x/token"}
    assert tokens("r1") == {f"{keys.frames(site.fleet, 'r1')}/@adv/pub/x/token"}
    for entity in declared:
        entity.undeclare()  # type: ignore[attr-defined]


@pytest.mark.usefixtures("router")
def test_a_fleet_wide_certificate_of_a_per_robot_fleet_may_do_nothing(
    site: SecureSite, session_as: Callable[..., zenoh.Session], tmp_path: Path
) -> None:
    # A robot.F certificate of the same CA (issued before F went per-robot) still passes TLS,
    # but the router has no subject for it: deny by default, both ways.
    folder = site.site.folder
    shared = robot_name(site.fleet)
    now = datetime.datetime.now(datetime.UTC)
    pki.issue(tmp_path, shared, pki.load_ca(folder), now, 1)
    conf = client_config(str(tmp_path), shared, site.endpoint)
    conf["transport"]["link"]["tls"]["root_ca_certificate"] = str(folder / "ca.pem")
    (tmp_path / "shared.json5").write_text(render(conf, "robot.F, issued before --robot"))
    old = open_session([site.endpoint], config_file=str(tmp_path / "shared.json5"), timeout_s=20)
    try:
        got = Collector(session_as("service"), keys.frames(site.fleet, "*"))
        publisher = old.declare_publisher(keys.frames(site.fleet, "r2"))
        r2 = session_as("robot", f"{site.fleet}/r2")
        for robot in ("r1", "r2"):
            old.put(keys.frames(site.fleet, robot), f"old on {robot}".encode())
        # Positive control: r2's own certificate, the same router and subscriber.
        put_until(r2, keys.frames(site.fleet, "r2"), b"r2", lambda: b"r2" in got.payloads())
        for robot in ("r1", "r2"):
            old.put(keys.frames(site.fleet, robot), f"old on {robot}".encode())
        time.sleep(QUIET_S)
        assert got.payloads() == {b"r2"}
        # Not even the service's subscription is forwarded to it (r2 learned it at once).
        status: Any = publisher.matching_status  # 1.10's stubs say bool; a MatchingStatus
        assert status.matching is False
        publisher.undeclare()
    finally:
        old.close()

"""A secured mesh: two routers with mTLS and access control between them and to every client.

Router A and router B run in this process with the configs ``lessmap certs --mesh`` writes
(certificates made now, random loopback ports). ``lessmap serve`` joins router A with the
service's certificate; robots and fleet apps join router B. Everything they exchange crosses
the router-to-router link, where each router presents its own certificate (``router.a``,
``router.b``) and gets the ``routers`` rules. The per-role rules still hold: each is enforced
by the router the robot or app is connected to. Every refusal is checked next to a positive
control on the same path.
"""

from __future__ import annotations

import json
import time
import uuid
from dataclasses import dataclass
from typing import TYPE_CHECKING

import pytest
import zenoh
from cryptography import x509

from lessmap.cli.app import main
from lessmap.errors import ConfigError
from lessmap.security.certs import TEMPLATE_MESH, Site, make_site
from lessmap.security.siteconfig import access_rules, mesh_router_config, render
from lessmap_client import connect
from lessmap_client.session import open_session
from lessmap_schemas import encode, encoding, keys
from lessmap_schemas.messages import Frame
from lessmap_schemas.partition import partition_of
from tests.conftest import ServeProcess, free_port, wait_until
from tests.security.conftest import crossed
from tests.security.test_certs import DEPLOY, common_name
from tests.security.test_mtls_e2e import collect, walk_two_rooms
from tests.security.test_partition_acl import Collector, answer_with, put_until, replies

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    from lessmap_client import Connection

pytestmark = pytest.mark.timeout(120)

#: How long a refused message gets to show up anyway, after the positive control arrived.
QUIET_S = 1.0


@dataclass
class Mesh:
    """A mesh site's files, its two routers' endpoints and its two fleets."""

    site: Site
    a: str  # router A's endpoint: the service's
    b: str  # router B's endpoint: the robots' and apps'
    fleet: str  # F: the fleet whose data is protected
    other: str  # G: another fleet of the same site

    def config(self, role: str, fleet: str | None = None) -> str:
        """Return the Zenoh config file of ``role`` (robot, app, service)."""
        if role == "service":
            return str(self.site.services["service"])
        table = self.site.robots if role == "robot" else self.site.apps
        return str(table[fleet or self.fleet])


@pytest.fixture
def mesh(tmp_path: Path, fleet_name: str) -> Mesh:
    """Certificates and configs of a two-router mesh for fleets F and G."""
    a, b = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    other = f"other-{uuid.uuid4().hex[:8]}"
    made = make_site(tmp_path / "site", [fleet_name, other], mesh={"a": a, "b": b})
    return Mesh(made, a, b, fleet_name, other)


def meshed(a: zenoh.Session, b: zenoh.Session) -> bool:
    """Return whether each router has the other as a router neighbour."""
    return set(a.info.routers_zid()) >= {b.zid()} and set(b.info.routers_zid()) >= {a.zid()}


@pytest.fixture
def routers(mesh: Mesh) -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """Routers A and B (mTLS on every link, access control), meshed, in this process."""
    with (
        zenoh.open(zenoh.Config.from_file(str(mesh.site.routers["a"]))) as a,
        zenoh.open(zenoh.Config.from_file(str(mesh.site.routers["b"]))) as b,
    ):
        wait_until(lambda: meshed(a, b), 20.0, "routers A and B to connect over mTLS")
        yield a, b


@pytest.fixture
def service(
    routers: tuple[zenoh.Session, zenoh.Session],
    mesh: Mesh,
    serve: Callable[..., ServeProcess],
) -> ServeProcess:
    """``lessmap serve`` joining router A (only) with the service's certificate."""
    return serve(
        "--zenoh-config",
        mesh.config("service"),
        "-m",
        "client",
        "--cfg",
        "listen/endpoints:[]",
        "--cfg",
        f"connect/endpoints:{json.dumps([mesh.a])}",
        "--memory-only",
    )


@pytest.fixture
def connect_b(mesh: Mesh) -> Iterator[Callable[..., Connection]]:
    """Open SDK connections to router B with one role's config; closed at teardown."""
    opened: list[Connection] = []

    def open_as(role: str, fleet: str | None = None) -> Connection:
        conn = connect(mesh.b, config_file=mesh.config(role, fleet), timeout_s=20.0)
        opened.append(conn)
        return conn

    yield open_as
    for conn in reversed(opened):
        conn.close()


@pytest.fixture
def session_at(mesh: Mesh) -> Iterator[Callable[..., zenoh.Session]]:
    """Open raw Zenoh sessions to router ``a`` or ``b`` with one role's config."""
    opened: list[zenoh.Session] = []

    def open_as(router: str, role: str, fleet: str | None = None) -> zenoh.Session:
        endpoint = mesh.a if router == "a" else mesh.b
        session = open_session([endpoint], config_file=mesh.config(role, fleet), timeout_s=20)
        opened.append(session)
        return session

    yield open_as
    for session in reversed(opened):
        session.close()


def put_until_true(put: Callable[[], None], seen: Callable[[], bool], what: str) -> None:
    """Call ``put`` until ``seen()`` (declarations take a moment to cross the mesh)."""

    def done() -> bool:
        if not seen():
            put()
            time.sleep(0.2)
        return seen()

    wait_until(done, 20.0, what)


# -- the flow across the mesh ------------------------------------------------------------------


def test_a_robot_and_an_app_on_router_b_work_with_the_service_on_router_a(
    mesh: Mesh,
    service: ServeProcess,
    connect_b: Callable[..., Connection],
    session_at: Callable[..., zenoh.Session],
) -> None:
    app = connect_b("app")
    assert app.wait_for_service(20.0), service.log()  # the instance's token crossed A -> B
    events = app.subscribe_transitions(mesh.fleet)
    robot = connect_b("robot").robot(mesh.fleet, "amr-1")
    assert robot.wait_for_service(10.0)
    wait_until(lambda: robot.status.owner == service.instance, 10.0, "the robot's owner")
    # The service's frames subscriber is known on B, the app's transitions subscriber on A.
    crossed(session_at("b", "robot"), keys.frames(mesh.fleet, "amr-1"), "frames sub at B")
    crossed(session_at("a", "service"), keys.transitions(mesh.fleet, "amr-1"), "app sub at A")
    walk_two_rooms(robot)  # frames B -> A, transitions A -> B

    deadline = time.monotonic() + 20.0
    while (s := app.state(mesh.fleet, "amr-1")) is None or s.frames_applied < 40:
        assert time.monotonic() < deadline, (s, robot.status, service.log())
        time.sleep(0.1)
    assert s.frames_applied == 40, s  # the state query crossed B -> A -> B
    transition = events.recv(timeout_s=20.0)
    assert transition is not None, (app.state(mesh.fleet, "amr-1"), service.log())
    assert (transition.fleet, transition.robot) == (mesh.fleet, "amr-1")
    assert transition.instance == service.instance
    assert [h.instance for h in app.health()] == [service.instance]
    state = robot.state()
    assert state is not None
    assert state.transitions == 1


def test_a_robot_of_another_fleet_on_router_b_cannot_feed_this_fleet(
    mesh: Mesh,
    service: ServeProcess,
    connect_b: Callable[..., Connection],
    session_at: Callable[..., zenoh.Session],
) -> None:
    app = connect_b("app")
    assert app.wait_for_service(20.0), service.log()
    intruder = session_at("b", "robot", mesh.other)  # robot.G, a valid certificate
    own = connect_b("app", mesh.other)
    frame = Frame(session="s-intrude", seq=0, stamp_s=0.0, features=[1, 2, 3])

    def put(fleet: str, robot: str, seqs: range) -> None:
        for seq in seqs:
            payload = encode(frame.model_copy(update={"seq": seq}))
            intruder.put(keys.frames(fleet, robot), payload, encoding=encoding(frame))

    def applied(count: int) -> Callable[[], bool]:
        def done() -> bool:
            state = own.state(mesh.other, "own")
            return state is not None and state.frames_applied == count

        return done

    # Positive control: the same session feeds its own fleet across the mesh (repeated
    # until the service's subscriber is known at B; repeats are duplicates, not applied).
    put_until_true(lambda: put(mesh.other, "own", range(5)), applied(5), "G's own frames")
    put(mesh.fleet, "victim", range(5))  # robot G on F's robot's key: refused at B
    put(mesh.other, "own", range(5, 10))  # and again its own, after the refused ones
    wait_until(applied(10), 20.0, "robot G's later frames to be applied")
    time.sleep(QUIET_S)
    assert app.state(mesh.fleet, "victim") is None
    assert app.states(mesh.fleet) == []


def test_an_app_of_another_fleet_on_router_b_receives_nothing_of_this_fleet(
    mesh: Mesh,
    service: ServeProcess,
    connect_b: Callable[..., Connection],
    session_at: Callable[..., zenoh.Session],
) -> None:
    spy = connect_b("app", mesh.other)  # app.G
    assert spy.wait_for_service(20.0), service.log()
    spy_events = spy.subscribe_transitions(mesh.fleet)
    sub, spied = collect(session_at("b", "app", mesh.other), keys.transitions("*", "*"))
    app = connect_b("app")
    events = app.subscribe_transitions(mesh.fleet)

    robot = connect_b("robot").robot(mesh.fleet, "amr-1")
    assert robot.wait_for_service(10.0)
    crossed(session_at("b", "robot"), keys.frames(mesh.fleet, "amr-1"), "frames sub at B")
    crossed(session_at("a", "service"), keys.transitions(mesh.fleet, "amr-1"), "app sub at A")
    walk_two_rooms(robot)
    assert events.recv(timeout_s=20.0) is not None, service.log()  # positive control
    time.sleep(QUIET_S)
    assert spy_events.try_recv() is None
    assert spied == []
    sub.undeclare()
    assert spy.state(mesh.fleet, "amr-1") is None
    assert spy.states(mesh.fleet) == []


@pytest.mark.usefixtures("routers")
def test_checkpoints_cross_the_mesh_between_service_identities_only(
    mesh: Mesh, session_at: Callable[..., zenoh.Session]
) -> None:
    # Raw sessions play the instances: the owner on router A, the standby on router B.
    p = partition_of(mesh.fleet, "amr-1")
    key = keys.checkpoints(p, mesh.fleet, "amr-1")
    owner, standby = session_at("a", "service"), session_at("b", "service")
    followed = Collector(standby, keys.checkpoints())
    # Spies and forgers on router B, in separate sessions (a session receives its own puts).
    spying = {"app.F": session_at("b", "app"), "robot.F": session_at("b", "robot")}
    spies = {n: Collector(s, f"{keys.KEY_PREFIX}/@/checkpoints/**") for n, s in spying.items()}
    outsiders = {"app.F": session_at("b", "app"), "robot.F": session_at("b", "robot")}
    declared = [
        forger.declare_queryable(keys.checkpoints(p), answer_with(key, b"forged"))
        for forger in outsiders.values()
    ]
    put_until(owner, key, b"real", lambda: b"real" in followed.payloads())
    for name, forger in outsiders.items():
        forger.put(key, f"forged by {name}".encode())
    declared.append(owner.declare_queryable(keys.checkpoints(p), answer_with(key, b"real")))
    put_until(owner, key, b"real again", lambda: b"real again" in followed.payloads())
    time.sleep(QUIET_S)
    assert followed.payloads() == {b"real", b"real again"}
    # The hand-over query from B reaches the owner's queryable on A, and no forger's.
    assert replies(standby, keys.checkpoints(p, "*", "*"), 3.0) == {b"real"}
    for name, session in spying.items():
        assert spies[name].got == [], name
        assert replies(session, key, 1.0) == set(), name
    for entity in declared:
        entity.undeclare()


def test_without_a_subject_for_the_routers_the_mesh_relays_nothing(tmp_path: Path) -> None:
    # The gap the routers' identities close: with the single-router rules on both routers
    # (no `routers` subject), the routers connect over mTLS and forward each other nothing.
    a, b = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    made = make_site(tmp_path / "site", ["f"], mesh={"a": a, "b": b})
    folder, ends = str(made.folder), {"a": a, "b": b}
    paths = {}
    for name in ends:
        conf = mesh_router_config(folder, name, ends, ["f"], ["service"])
        conf["access_control"] = access_rules(["f"], ["service"])
        paths[name] = made.folder / f"no-router-subject-{name}.json5"
        paths[name].write_text(render(conf, "test"))
    with (
        zenoh.open(zenoh.Config.from_file(str(paths["a"]))) as ra,
        zenoh.open(zenoh.Config.from_file(str(paths["b"]))) as rb,
    ):
        wait_until(lambda: meshed(ra, rb), 20.0, "routers A and B to connect over mTLS")
        service = open_session([a], config_file=str(made.services["service"]), timeout_s=20)
        near = open_session([a], config_file=str(made.robots["f"]), timeout_s=20)
        robot = open_session([b], config_file=str(made.robots["f"]), timeout_s=20)
        try:
            got = Collector(service, keys.frames("*", "*"))
            # Positive control: the same robot identity on router A reaches the subscriber.
            put_until(near, keys.frames("f", "r"), b"on A", lambda: b"on A" in got.payloads())
            for _ in range(10):
                robot.put(keys.frames("f", "r"), b"from B")
                time.sleep(0.1)
            time.sleep(QUIET_S)
            assert got.payloads() == {b"on A"}
        finally:
            for session in (robot, near, service):
                session.close()


# -- what `lessmap certs --mesh` writes --------------------------------------------------------


def test_the_routers_subject_relays_every_lessmap_key_and_changes_no_role() -> None:
    # The single-router rules have no subject for the routers; the mesh's add one.
    single = access_rules(["f"], ["service"])
    meshed_rules = access_rules(["f"], ["service"], routers=["router.a", "router.b"])
    assert not any("router" in json.dumps(s) for s in single["subjects"])
    subject = next(s for s in meshed_rules["subjects"] if s["id"] == "routers")
    assert subject["cert_common_names"] == ["router.a", "router.b"]
    # Routers relay every lessmap key both ways, each `@` key named; the roles' rules are
    # the same as without a mesh.
    relayed = {r["id"]: r for r in meshed_rules["rules"] if r["id"].startswith("router-")}
    assert {r["flows"][0] for r in relayed.values()} == {"ingress", "egress"}
    for rule in relayed.values():
        assert f"{keys.KEY_PREFIX}/@/checkpoints/**" in rule["key_exprs"]
        assert f"{keys.KEY_PREFIX}/*/*/frames/*/@adv/**" in rule["key_exprs"]
    others = [r for r in meshed_rules["rules"] if not r["id"].startswith("router-")]
    assert others == single["rules"]


def test_a_mesh_site_has_one_certificate_per_router_naming_its_host(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "site"
    args = ["certs", "--out", str(out), "--fleet", "lab"]
    mesh = ["--mesh", "a=tls/127.0.0.2:7447", "--mesh", "b=tls/router-b.lan:7447"]
    assert main([*args, *mesh]) == 0
    written = json.loads(capsys.readouterr().out)
    assert set(written["routers"]) == {"a", "b"}
    for name, host in (("a", "127.0.0.2"), ("b", "router-b.lan")):
        pem = out / f"router.{name}.pem"
        assert common_name(pem) == f"router.{name}"
        cert = x509.load_pem_x509_certificate(pem.read_bytes())
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        names = [str(v) for v in san.get_values_for_type(x509.IPAddress)]
        names += san.get_values_for_type(x509.DNSName)
        assert host in names
        conf = zenoh.Config.from_file(written["routers"][name])
        assert json.loads(conf.get_json("connect/endpoints")) == [
            e for n, e in (("a", "tls/127.0.0.2:7447"), ("b", "tls/router-b.lan:7447")) if n != name
        ]
    assert not (out / "router.pem").exists()
    # Clients list both routers: they connect to whichever answers.
    robot = zenoh.Config.from_file(written["robots"]["lab"])
    assert json.loads(robot.get_json("connect/endpoints")) == [
        "tls/127.0.0.2:7447",
        "tls/router-b.lan:7447",
    ]


@pytest.mark.parametrize(
    "mesh",
    [
        ["a=tls/127.0.0.1:7447"],  # a mesh of one
        ["a=tls/127.0.0.1:7447", "b=tcp/127.0.0.1:7448"],  # not TLS
        ["a=tls/127.0.0.1:7447", "b=tls/127.0.0.1:7447"],  # one endpoint for two
        ["a=tls/127.0.0.1:7447", "a=tls/127.0.0.1:7448"],  # one name for two
        ["a=tls/127.0.0.1:7447", "tls/127.0.0.1:7448"],  # no name
    ],
)
def test_a_bad_mesh_is_refused(tmp_path: Path, mesh: list[str]) -> None:
    args = ["certs", "--out", str(tmp_path), "--fleet", "f"]
    assert main([*args, *(a for m in mesh for a in ("--mesh", m))]) == 1
    assert not (tmp_path / "ca.key").exists()


def test_a_service_name_cannot_pass_for_a_router(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="clash"):
        make_site(tmp_path, ["f"], ["router.a"])


def test_the_deploy_mesh_routers_connect_to_each_other() -> None:
    a = zenoh.Config.from_file(str(DEPLOY / "zenoh-router-a-mtls.json5"))
    b = zenoh.Config.from_file(str(DEPLOY / "zenoh-router-b-mtls.json5"))
    assert json.loads(a.get_json("listen/endpoints")) == [TEMPLATE_MESH["a"]]
    assert json.loads(a.get_json("connect/endpoints")) == [TEMPLATE_MESH["b"]]
    assert json.loads(b.get_json("listen/endpoints")) == [TEMPLATE_MESH["b"]]
    assert json.loads(b.get_json("connect/endpoints")) == [TEMPLATE_MESH["a"]]
    # The same addresses as the plain pair.
    for name, conf in (("a", a), ("b", b)):
        plain = zenoh.Config.from_file(str(DEPLOY / f"zenoh-router-{name}.json5"))
        for key in ("listen/endpoints", "connect/endpoints"):
            got = [e.replace("tls/", "tcp/") for e in json.loads(conf.get_json(key))]
            assert got == json.loads(plain.get_json(key)), (name, key)

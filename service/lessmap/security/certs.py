"""``lessmap certs``: a test site's CA, certificates and Zenoh configs (mTLS + access control).

Who may do what is decided by the router, from the common name (CN) of the certificate a
session presents: ``robot.<fleet>`` (or ``robot.<fleet>/<robot>``, one per robot, with
``--robot FLEET/ROBOT``), ``app.<fleet>``, ``viewer.<fleet>`` (``lessmap view``: an app's
reads and the robots' frames), the service names (``service`` by default) and, for a mesh of
routers (``--mesh NAME=ENDPOINT``), ``router.<name>``.
``lessmap.security.siteconfig.access_rules`` is the one place that maps those roles to Zenoh
``access_control`` rules; the router configs this command writes and the templates in ``deploy/``
(``--templates``) are both rendered from it, so they cannot drift apart.

Private keys are written with mode 0600 and never overwritten silently: an existing CA is kept
unless ``--force`` is given (a new CA invalidates every certificate issued before).
"""

from __future__ import annotations

import datetime
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap.errors import ConfigError
from lessmap.security.siteconfig import (
    DEFAULT_ENDPOINT,
    TEMPLATE_DIR,
    TEMPLATE_FLEET,
    app_name,
    client_config,
    identity_file,
    mesh_router_config,
    render,
    robot_name,
    router_config,
    router_name,
    usrpwd_client_config,
    usrpwd_router_config,
    viewer_name,
)
from lessmap_schemas import keys

if TYPE_CHECKING:
    import argparse
    from collections.abc import Iterable, Mapping, Sequence


# -- the site -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Site:
    """What ``make_site`` wrote: the folder and every config file, by role.

    ``router`` is the single router's config; for a mesh, the first mesh router's, and
    ``routers`` holds every mesh router's config by name. ``robots`` holds the robot configs
    by fleet (``F``), and by ``F/R`` for the robots with identities of their own.
    """

    folder: Path
    router: Path
    services: dict[str, Path]
    robots: dict[str, Path]
    apps: dict[str, Path]
    routers: dict[str, Path] = field(default_factory=dict)
    viewers: dict[str, Path] = field(default_factory=dict)


def _check_names(
    fleets: Sequence[str],
    service_names: Sequence[str],
    mesh: Mapping[str, str] | None = None,
    robots: Mapping[str, Sequence[str]] | None = None,
) -> None:
    if not fleets:
        msg = "give at least one --fleet"
        raise ConfigError(msg)
    robots = robots or {}
    robot_names = [name for names in robots.values() for name in names]
    for name in [*fleets, *service_names, *robot_names]:
        what = "fleet" if name in fleets else "robot" if name in robot_names else "service name"
        try:
            keys.validate_name(name, what)
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
    for fleet, names in robots.items():
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:
            msg = f"--robot {fleet}/{twice[0]} is given twice"
            raise ConfigError(msg)
    for name in service_names:
        if name == "router" or name.startswith(("router.", "robot.", "app.", "ca")):
            msg = f"service name {name!r} would clash with another identity"
            raise ConfigError(msg)
    if len(set(fleets)) != len(fleets) or len(set(service_names)) != len(service_names):
        msg = "fleet and service names must be distinct"
        raise ConfigError(msg)
    mesh = mesh or {}
    if mesh and len(mesh) < 2:
        msg = "a mesh needs at least two --mesh routers"
        raise ConfigError(msg)
    for name, endpoint in mesh.items():
        try:
            keys.validate_name(name, "router name")
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
        _endpoint_host(endpoint)
    if len(set(mesh.values())) != len(mesh):
        msg = "each --mesh router needs an endpoint of its own"
        raise ConfigError(msg)


def _endpoint_host(endpoint: str) -> str:
    """Return the host of a ``tls/HOST:PORT`` endpoint (what the certificate must name)."""
    proto, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if proto != "tls" or not host or not port.isdigit():
        msg = f"{endpoint!r} is not a tls/HOST:PORT endpoint"
        raise ConfigError(msg)
    return host


def parse_mesh(values: Sequence[str]) -> dict[str, str]:
    """Return ``--mesh NAME=ENDPOINT`` values as a name to endpoint mapping, in order.

    Raises:
        ConfigError: a value without ``=``, or a name given twice.
    """
    mesh: dict[str, str] = {}
    for value in values:
        name, sep, endpoint = value.partition("=")
        if not sep or not name or not endpoint:
            msg = f"--mesh {value!r}: give NAME=ENDPOINT, e.g. a=tls/10.0.0.5:7447"
            raise ConfigError(msg)
        if name in mesh:
            msg = f"--mesh: router {name!r} given twice"
            raise ConfigError(msg)
        mesh[name] = endpoint
    return mesh


def parse_robots(values: Sequence[str]) -> dict[str, list[str]]:
    """Return ``--robot FLEET/ROBOT`` values as fleet to robot names, in order.

    Raises:
        ConfigError: a value that is not two chunks around one ``/``.
    """
    robots: dict[str, list[str]] = {}
    for value in values:
        fleet, sep, robot = value.partition("/")
        if not sep or not fleet or not robot or "/" in robot:
            msg = f"--robot {value!r}: give FLEET/ROBOT, e.g. warehouse/amr-7"
            raise ConfigError(msg)
        robots.setdefault(fleet, []).append(robot)
    return robots


def _check_common_names(identities: Sequence[str]) -> None:
    # X.509 caps a CN at 64 characters (RFC 5280, ub-common-name).
    for identity in identities:
        if len(identity) > 64:
            msg = (
                f"certificate CN {identity!r} has {len(identity)} characters (at most 64): "
                "use shorter fleet or robot names"
            )
            raise ConfigError(msg)


def make_site(
    out: Path,
    fleets: Sequence[str],
    service_names: Sequence[str] = ("service",),
    *,
    endpoint: str = DEFAULT_ENDPOINT,
    router_hosts: Iterable[str] = (),
    mesh: Mapping[str, str] | None = None,
    robots: Mapping[str, Sequence[str]] | None = None,
    days: int = 365,
    force: bool = False,
    reuse_ca: bool = False,
) -> Site:
    """Write a CA, one certificate per identity and the Zenoh configs of a test site.

    Args:
        out: the folder (created); configs name its absolute path.
        fleets: a robot, an app and a viewer identity per fleet.
        service_names: one identity per name (certificate CN).
        endpoint: where the single router listens and the clients connect.
        router_hosts: more DNS names or IP addresses in the router certificates (SAN).
        mesh: routers of a mesh, name to TLS endpoint (at least two), instead of one.
        robots: fleet to robot names, each robot with an identity of its own
            (``robot.<fleet>/<robot>``); its fleet gets no fleet-wide robot identity.
        days: validity of every certificate.
        force: replace an existing CA (every older certificate stops working).
        reuse_ca: keep the CA in ``out`` and issue new certificates and keys from it.
    """
    from lessmap.security import pki

    mesh = dict(mesh or {})
    robots = {fleet: list(names) for fleet, names in (robots or {}).items() if names}
    fleets = [*fleets, *(fleet for fleet in robots if fleet not in fleets)]
    _check_names(fleets, service_names, mesh, robots)
    identities = [*service_names]
    for fleet in fleets:
        own = [robot_name(fleet, r) for r in robots[fleet]] if fleet in robots else []
        identities += [*(own or [robot_name(fleet)]), app_name(fleet), viewer_name(fleet)]
    _check_common_names([*identities, *(router_name(name) for name in mesh)])
    out.mkdir(parents=True, exist_ok=True)
    folder = out.resolve()
    now = datetime.datetime.now(datetime.UTC)
    if reuse_ca:
        ca = pki.load_ca(folder)
    elif (folder / "ca.key").exists() and not force:
        msg = (
            f"{out / 'ca.key'} exists: give --reuse-ca to issue new certificates from it, "
            "or --force to replace the CA"
        )
        raise ConfigError(msg)
    else:
        ca = pki.new_ca(folder, now, days)
    hosts = ["127.0.0.1", "localhost", *router_hosts]
    if mesh:
        for name, listen in mesh.items():
            own_hosts = [*hosts, _endpoint_host(listen)]
            pki.issue(folder, router_name(name), ca, now, days, list(dict.fromkeys(own_hosts)))
    else:
        pki.issue(folder, "router", ca, now, days, hosts)
    for identity in identities:
        pki.issue(folder, identity, ca, now, days, stem=identity_file(identity))

    header = (
        f"Written by `lessmap certs` for fleets {', '.join(fleets)}.\n"
        "See docs/SECURITY.md; every path below is in this folder."
    )
    d = str(folder)
    routers = {}
    if mesh:
        for name in mesh:
            routers[name] = folder / f"zenoh-router-{name}-mtls.json5"
            conf = mesh_router_config(d, name, mesh, fleets, service_names, robots)
            routers[name].write_text(render(conf, header))
        router = next(iter(routers.values()))
        connect: str | list[str] = list(mesh.values())
    else:
        router = folder / "zenoh-router-mtls.json5"
        conf = router_config(d, fleets, service_names, endpoint, robots)
        router.write_text(render(conf, header))
        connect = endpoint
    services = {}
    for name in service_names:
        services[name] = folder / f"zenoh-{name}-mtls.json5"
        services[name].write_text(render(client_config(d, name, connect), header))
    configs, apps, viewers = {}, {}, {}
    for fleet in fleets:
        for robot in robots.get(fleet, []):
            path = folder / "robots" / fleet / f"zenoh-{robot}-mtls.json5"
            configs[f"{fleet}/{robot}"] = path
            path.write_text(render(client_config(d, robot_name(fleet, robot), connect), header))
        if fleet not in robots:
            configs[fleet] = folder / f"zenoh-robot-{fleet}-mtls.json5"
            configs[fleet].write_text(render(client_config(d, robot_name(fleet), connect), header))
        apps[fleet] = folder / f"zenoh-app-{fleet}-mtls.json5"
        apps[fleet].write_text(render(client_config(d, app_name(fleet), connect), header))
        viewers[fleet] = folder / f"zenoh-viewer-{fleet}-mtls.json5"
        viewers[fleet].write_text(render(client_config(d, viewer_name(fleet), connect), header))
    return Site(folder, router, services, configs, apps, routers, viewers)


# -- templates (deploy/) ------------------------------------------------------------------------

ROUTER_NOTE = """\
Template: replace FLEET by your fleet's name; for more fleets, repeat the FLEET rules, subjects
and policy per fleet, or let `lessmap certs --out DIR --fleet F [--fleet G]` write this file
filled in. Put the files it names in {folder}. See docs/SECURITY.md.
Listens on loopback only. To open it, listen on the address of one interface, e.g.
"tls/10.0.0.5:7447" (never 0.0.0.0), with that name or IP in the router's certificate
(`lessmap certs --router-host 10.0.0.5`).
"""

CLIENT_NOTE = """\
Template: replace FLEET by your fleet's name and 127.0.0.1 by the router's address (a name or
IP in its certificate), and put the files it names in {folder}; `lessmap certs` writes it
filled in. See docs/SECURITY.md.
"""


MESH_NOTE = """\
Template: router {name} of a two-router mesh (zenoh-router-{other}-mtls.json5 is the other).
Replace FLEET as in zenoh-router-mtls.json5, and {own} (this machine) and {peer} (router
{other}'s) by your addresses, each named in its router's certificate (CN router.{name} and
router.{other}), or let `lessmap certs --out DIR --fleet F --mesh a=tls/HOST_A:7447
--mesh b=tls/HOST_B:7447` write both filled in. Put the files it names in {folder}.
Each router presents its certificate when it accepts and when it dials the other; the
other router's CN has the `routers` rules (every lessmap message, both ways), each robot,
app and service its own rules at the router it connects to. See docs/SECURITY.md.
"""

#: The mesh of the templates: the addresses of deploy/zenoh-router-{a,b}.json5.
TEMPLATE_MESH = {"a": "tls/10.0.0.5:7447", "b": "tls/10.0.0.6:7447"}


def templates() -> dict[str, str]:
    """Return the deploy/ config templates, by file name (placeholder fleet and paths)."""
    d, fleet, service = TEMPLATE_DIR, TEMPLATE_FLEET, "service"

    def router(what: str) -> str:
        return what + "\n" + ROUTER_NOTE.format(folder=d)

    def client(what: str) -> str:
        return what + "\n" + CLIENT_NOTE.format(folder=d)

    def mesh_router(name: str) -> str:
        other = next(n for n in TEMPLATE_MESH if n != name)
        return render(
            mesh_router_config(d, name, TEMPLATE_MESH, [fleet], [service]),
            f"Zenoh router {name} of a lessmap mesh: TLS, certificates required on every link\n"
            "(clients and the other router), deny-by-default access control by certificate CN.\n"
            f"Run: lessmap router -c zenoh-router-{name}-mtls.json5 (or zenohd -c ...).\n"
            + MESH_NOTE.format(
                name=name,
                other=other,
                own=TEMPLATE_MESH[name].split("/")[1].split(":")[0],
                peer=TEMPLATE_MESH[other].split("/")[1].split(":")[0],
                folder=d,
            ),
        )

    return {
        "zenoh-router-a-mtls.json5": mesh_router("a"),
        "zenoh-router-b-mtls.json5": mesh_router("b"),
        "zenoh-router-mtls.json5": render(
            router_config(d, [fleet], [service]),
            router(
                "Zenoh router for lessmap: TLS, client certificates required (mTLS), and\n"
                "access control that denies everything not allowed below, by certificate CN.\n"
                "Run: zenohd -c zenoh-router-mtls.json5 (or any Zenoh router, e.g. Python's)."
            ),
        ),
        "zenoh-service-mtls.json5": render(
            client_config(d, service),
            client("A lessmap service instance (CN service): `lessmap serve --zenoh-config THIS`."),
        ),
        "zenoh-robot-mtls.json5": render(
            client_config(d, robot_name(fleet)),
            client(
                "A robot of FLEET (certificate CN robot.FLEET):\n"
                "lessmap_client.connect(endpoint, config_file=THIS).robot(FLEET, name)."
            ),
        ),
        "zenoh-fleetapp-mtls.json5": render(
            client_config(d, app_name(fleet)),
            client(
                "A fleet app of FLEET (certificate CN app.FLEET):\n"
                "lessmap_client.connect(endpoint, config_file=THIS)."
            ),
        ),
        "zenoh-router-usrpwd.json5": render(
            usrpwd_router_config(d, [fleet], [service]),
            router(
                "Zenoh router for lessmap: TLS (server certificate only), a user name and\n"
                "password per role (credentials.txt: one `user:password` line each, mode 0600),\n"
                "access control by user name. Prefer mTLS (zenoh-router-mtls.json5)."
            ),
        ),
        "zenoh-robot-usrpwd.json5": render(
            usrpwd_client_config(d, robot_name(fleet)),
            client(
                "A robot of FLEET logging in as robot.FLEET (zenoh-router-usrpwd.json5).\n"
                "Set the password and keep this file mode 0600; app.FLEET and service log\n"
                "in the same way with their own user names."
            ),
        ),
    }


# -- the command --------------------------------------------------------------------------------


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap certs``."""
    parser.description = (
        "Write a test site's CA, a router certificate (SAN 127.0.0.1, localhost) or one per "
        "mesh router (CN router.NAME, --mesh), one certificate and key per role and fleet "
        "(CN robot.F, app.F, and the service names) or per robot (CN robot.F/R, --robot), "
        "and the Zenoh configs of each role with mTLS and deny-by-default access control. "
        "Keys are written mode 0600. See docs/SECURITY.md."
    )
    parser.add_argument(
        "-o", "--out", type=Path, required=True, metavar="DIR", help="folder to write to"
    )
    parser.add_argument(
        "--fleet", action="append", default=[], help="a fleet name (repeat for more fleets)"
    )
    parser.add_argument(
        "--service-names",
        nargs="+",
        default=["service"],
        metavar="NAME",
        help="certificate CN of each service identity (default: service)",
    )
    parser.add_argument(
        "--endpoint",
        default=DEFAULT_ENDPOINT,
        help=f"where the router listens and clients connect (default: {DEFAULT_ENDPOINT})",
    )
    parser.add_argument(
        "--router-host",
        action="append",
        default=[],
        metavar="HOST",
        help="another DNS name or IP address of the router (its certificate's SAN)",
    )
    parser.add_argument(
        "--mesh",
        action="append",
        default=[],
        metavar="NAME=ENDPOINT",
        help=(
            "a router of a mesh and where it listens, e.g. a=tls/10.0.0.5:7447 (repeat, at "
            "least two): a certificate router.NAME per router and a config each that connects "
            "to the others; clients' configs list every router (--endpoint is then unused)"
        ),
    )
    parser.add_argument(
        "--robot",
        action="append",
        default=[],
        metavar="FLEET/ROBOT",
        help=(
            "a robot with an identity of its own, CN robot.FLEET/ROBOT, that may put only its "
            "own frames (repeat; its fleet then gets no shared robot.FLEET identity, and "
            "--fleet FLEET is implied)"
        ),
    )
    parser.add_argument("--days", type=int, default=365, help="validity (default: 365)")
    ca = parser.add_mutually_exclusive_group()
    ca.add_argument("--force", action="store_true", help="replace an existing CA")
    ca.add_argument(
        "--reuse-ca",
        action="store_true",
        help="keep the CA in --out and re-issue every certificate and key from it",
    )
    parser.add_argument(
        "--templates",
        action="store_true",
        help="write only the config templates of deploy/ (placeholder fleet FLEET) to --out",
    )


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap certs``."""
    if args.templates:
        args.out.mkdir(parents=True, exist_ok=True)
        for name, text in templates().items():
            (args.out / name).write_text(text, encoding="utf-8")
        return 0
    if args.days < 1:
        msg = "--days must be at least 1"
        raise ConfigError(msg)
    site = make_site(
        args.out,
        args.fleet,
        args.service_names,
        endpoint=args.endpoint,
        router_hosts=args.router_host,
        mesh=parse_mesh(args.mesh),
        robots=parse_robots(args.robot),
        days=args.days,
        force=args.force,
        reuse_ca=args.reuse_ca,
    )
    files: dict[str, object] = {
        "router": str(site.router),
        "services": {k: str(v) for k, v in site.services.items()},
        "robots": {k: str(v) for k, v in site.robots.items()},
        "apps": {k: str(v) for k, v in site.apps.items()},
        "viewers": {k: str(v) for k, v in site.viewers.items()},
    }
    if site.routers:
        files["routers"] = {k: str(v) for k, v in site.routers.items()}
    sys.stdout.write(json.dumps(files) + "\n")
    return 0

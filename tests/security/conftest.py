"""A test site over real TLS on loopback: certificates made now, a router, a service.

The certificates come from ``lessmap certs``'s own code (``make_site``) into ``tmp_path``;
nothing secret is in the repository. The router is opened in the test process with the
site's router config (mTLS + deny-by-default access control); ``lessmap serve`` joins it as
a client with the service's config, as a deployment would.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import pytest
import zenoh

from lessmap.security.certs import Site, make_site
from lessmap_client import connect
from lessmap_client.session import open_session
from tests.conftest import ServeProcess, free_port, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence
    from pathlib import Path

    from lessmap_client import Connection


@dataclass
class SecureSite:
    """The site's files, its router endpoint and its two fleets."""

    site: Site
    endpoint: str
    fleet: str  # F: the fleet whose data is protected
    other: str  # G: another fleet of the same site

    def config(self, role: str, fleet: str | None = None) -> str:
        """Return the Zenoh config file of ``role`` (robot, app, viewer, service).

        ``fleet`` is a fleet name, or ``F/R`` for a robot with an identity of its own.
        """
        if role == "service":
            return str(self.site.services["service"])
        table = {"robot": self.site.robots, "app": self.site.apps, "viewer": self.site.viewers}
        return str(table[role][fleet or self.fleet])


def secure_site(folder: Path, fleet: str, robots: Sequence[str] = ()) -> SecureSite:
    """Certificates and configs for fleets F and G, the router on a free loopback port.

    ``robots`` are robots of F with identities of their own (``--robot F/R``): their
    configs are ``config("robot", "F/R")``, and F has no fleet-wide robot identity.
    """
    endpoint = f"tls/127.0.0.1:{free_port()}"
    other = f"other-{uuid.uuid4().hex[:8]}"
    made = make_site(folder, [fleet, other], endpoint=endpoint, robots={fleet: list(robots)})
    return SecureSite(made, endpoint, fleet, other)


@pytest.fixture
def site(tmp_path: Path, fleet_name: str) -> SecureSite:
    """Fleets F and G, each with a fleet-wide robot identity (a module may override this)."""
    return secure_site(tmp_path / "site", fleet_name)


@pytest.fixture
def router(site: SecureSite) -> Iterator[zenoh.Session]:
    """The site's router (mTLS, access control), in this process."""
    with zenoh.open(zenoh.Config.from_file(str(site.site.router))) as session:
        yield session


@pytest.fixture
def service(
    router: zenoh.Session, site: SecureSite, serve: Callable[..., ServeProcess]
) -> ServeProcess:
    """``lessmap serve`` joining the router with the service's certificate."""
    # The serve fixture makes a loopback router; turn it into a client of the site's router
    # that listens nowhere (a client with listen endpoints would accept plain TCP).
    return serve(
        "--zenoh-config",
        site.config("service"),
        "-m",
        "client",
        "--cfg",
        "listen/endpoints:[]",
        "--memory-only",
    )


@pytest.fixture
def connect_as(site: SecureSite) -> Iterator[Callable[..., Connection]]:
    """Open SDK connections with one role's config; all are closed at teardown."""
    opened: list[Connection] = []

    def open_as(role: str, fleet: str | None = None) -> Connection:
        conn = connect(site.endpoint, config_file=site.config(role, fleet), timeout_s=20.0)
        opened.append(conn)
        return conn

    yield open_as
    for conn in reversed(opened):
        conn.close()


@pytest.fixture
def session_as(site: SecureSite) -> Iterator[Callable[..., zenoh.Session]]:
    """Open raw Zenoh sessions with one role's config (to try what the SDK never does)."""
    opened: list[zenoh.Session] = []

    def open_as(role: str, fleet: str | None = None) -> zenoh.Session:
        session = open_session([site.endpoint], config_file=site.config(role, fleet), timeout_s=20)
        opened.append(session)
        return session

    yield open_as
    for session in reversed(opened):
        session.close()


def crossed(session: zenoh.Session, key: str, what: str) -> None:
    """Wait until a publisher on ``key`` in ``session`` matches a subscriber (across the mesh).

    A writer sends only where a subscriber was declared to it; a declaration crosses two
    routers before a client on the other side learns of it.
    """
    publisher = session.declare_publisher(key)
    try:

        def matching() -> bool:
            # A fresh snapshot each time (eclipse-zenoh 1.10's stubs say bool; it is a
            # MatchingStatus).
            status: Any = publisher.matching_status
            return bool(status.matching)

        wait_until(matching, 20.0, what)
    finally:
        publisher.undeclare()

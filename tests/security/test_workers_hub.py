"""``serve --workers 2`` as a secured site's router: its workers meet it on a private socket.

The service itself is the site's router (mTLS, deny-by-default access control). Its
workers connect over a Unix socket in the parent's private folder, which the router's
access control lets in by its link protocol alone: no plain TCP listener is added, so
nothing on the machine reaches the router without a certificate of the site.
"""

from __future__ import annotations

import json
import re
import stat
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from tests.conftest import wait_until
from tests.security.test_mtls_e2e import walk_two_rooms

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap_client import Connection
    from tests.conftest import ServeProcess
    from tests.security.conftest import SecureSite

pytestmark = pytest.mark.timeout(180)


def test_a_secured_service_with_two_workers_serves_its_fleet(
    site: SecureSite,
    serve: Callable[..., ServeProcess],
    connect_as: Callable[..., Connection],
) -> None:
    service = serve(
        "--zenoh-config",
        str(site.site.router),
        "--cfg",
        f"listen/endpoints:{json.dumps([site.endpoint])}",
        "--workers",
        "2",
        "--memory-only",
    )
    app = connect_as("app")
    workers = {f"{service.instance}-w0", f"{service.instance}-w1"}
    wait_until(
        lambda: {h.instance for h in app.health()} == workers,
        60.0,
        "both workers to answer through the secured router",
        service.log,
    )
    # the workers' link: a Unix socket in a folder only this user can open, no TCP port
    found = re.search(r"their router on unixsock-stream/(\S+?)(?:\s|$)", service.log())
    assert found is not None, service.log()
    folder = Path(found.group(1)).parent
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert "tcp/127.0.0.1" not in service.log()

    events = app.subscribe_transitions(site.fleet)
    robots = [connect_as("robot").robot(site.fleet, f"amr-{i}") for i in range(6)]
    owners = set()
    for robot in robots:
        walk_two_rooms(robot)
        owners.add(robot.status.owner)
    assert owners == workers, "the robots' partitions are spread over both workers"
    seen = set()
    for _ in robots:
        transition = events.recv(timeout_s=20.0)
        assert transition is not None, service.log()
        seen.add(transition.robot)
    assert seen == {f"amr-{i}" for i in range(6)}

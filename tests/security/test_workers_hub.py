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
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from lessmap.security.certs import make_site
from lessmap.security.siteconfig import render, usrpwd_client_config, usrpwd_router_config
from lessmap_client import connect
from tests.conftest import free_port, wait_until
from tests.security.test_mtls_e2e import walk_two_rooms

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap_client import Connection
    from tests.conftest import ServeProcess
    from tests.security.conftest import SecureSite

pytestmark = pytest.mark.timeout(180)


def serve_two_workers(
    serve: Callable[..., ServeProcess], router_config: Path, endpoint: str
) -> ServeProcess:
    """``serve --workers 2`` as the router of ``router_config``, listening on ``endpoint`` only."""
    return serve(
        "--zenoh-config",
        str(router_config),
        "--cfg",
        f"listen/endpoints:{json.dumps([endpoint])}",
        "--workers",
        "2",
        "--memory-only",
    )


def both_answer(app: Connection, service: ServeProcess) -> set[str]:
    """Wait until both workers answer the app's health query; their instance names."""
    workers = {f"{service.instance}-w0", f"{service.instance}-w1"}
    wait_until(
        lambda: {h.instance for h in app.health()} == workers,
        60.0,
        "both workers to answer through the secured router",
        service.log,
    )
    return workers


def test_a_secured_service_with_two_workers_serves_its_fleet(
    site: SecureSite,
    serve: Callable[..., ServeProcess],
    connect_as: Callable[..., Connection],
) -> None:
    service = serve_two_workers(serve, site.site.router, site.endpoint)
    app = connect_as("app")
    workers = both_answer(app, service)
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


def test_a_user_password_router_hands_its_workers_its_own_user(
    tmp_path: Path, serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    endpoint = f"tls/127.0.0.1:{free_port()}"
    site = make_site(tmp_path / "site", [fleet_name], endpoint=endpoint)
    folder = str(site.folder)
    secrets = {"service": uuid.uuid4().hex, f"app.{fleet_name}": uuid.uuid4().hex}
    credentials = site.folder / "credentials.txt"
    credentials.write_text("".join(f"{user}:{word}\n" for user, word in secrets.items()))
    credentials.chmod(0o600)
    router = usrpwd_router_config(folder, [fleet_name], ["service"], endpoint)
    router["transport"]["auth"]["usrpwd"] |= {"user": "service", "password": secrets["service"]}
    router_file = site.folder / "router-usrpwd.json5"
    router_file.write_text(render(router, "test"))
    app_conf = usrpwd_client_config(folder, f"app.{fleet_name}", endpoint)
    app_conf["transport"]["auth"]["usrpwd"]["password"] = secrets[f"app.{fleet_name}"]
    app_file = site.folder / "app-usrpwd.json5"
    app_file.write_text(render(app_conf, "test"))

    service = serve_two_workers(serve, router_file, endpoint)
    with connect(endpoint, config_file=str(app_file), timeout_s=20.0) as app:
        both_answer(app, service)
    # the password went to the workers through their private files, not their command lines
    assert secrets["service"] not in service.log()

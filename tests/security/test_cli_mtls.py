"""Every networked command joins an mTLS site with ``-c`` and the config ``lessmap certs`` wrote.

The site's router (mTLS, deny-by-default access control) runs in this process and the
service joins it as a client (``tests/security/conftest.py``); each command then runs as a
user would run it, a subprocess given its role's config and nothing else: the endpoint
comes from the file.
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from pathlib import Path

    from tests.conftest import ServeProcess
    from tests.security.conftest import SecureSite

pytestmark = pytest.mark.timeout(240)


def lessmap(*argv: str) -> subprocess.CompletedProcess[str]:
    """Run ``python -m lessmap ARGV``; fail with its stderr if it does not exit 0."""
    result = subprocess.run(
        [sys.executable, "-m", "lessmap", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 0, (argv, result.stderr)
    assert ".rs:" not in result.stderr
    return result


def last_json(result: subprocess.CompletedProcess[str]) -> dict[str, object]:
    """The JSON object on the last line of stdout."""
    document: dict[str, object] = json.loads(result.stdout.strip().splitlines()[-1])
    return document


def test_every_networked_command_joins_the_site_with_its_roles_config(
    site: SecureSite, service: ServeProcess, tmp_path: Path
) -> None:
    fleet = site.fleet
    robot, app, viewer = site.config("robot"), site.config("app"), site.config("viewer")
    wait = ("--connect-timeout", "30")

    # Robots publish: a simulated fleet, then a recorded file, with the robot identity.
    sim = lessmap(
        "sim",
        "--publish",
        "--frames",
        "60",
        "--speed",
        "50",
        "--robots",
        "1",
        "--fleet",
        fleet,
        "-c",
        robot,
        *wait,
    )
    assert last_json(sim)["published"] == 60
    written = lessmap("sim", "--frames", "40", "--robots", "1", "-o", str(tmp_path / "run"))
    frames = str(last_json(written)["frames"])
    replayed = lessmap(
        "replay", frames, "--fast", "-c", robot, *wait, "--fleet", fleet, "--robot-prefix", "rec"
    )
    assert last_json(replayed)["ok"] is True

    # Fleet apps read, with the app identity: the instances, the places, the live view.
    status = lessmap("status", "--json", "-c", app, *wait)
    assert last_json(status)["instances"]
    areas = lessmap("areas", "--fleet", fleet, "--json", "-c", app, *wait)
    assert "robot0" in last_json(areas)["robots"]  # type: ignore[operator]
    watch = lessmap("watch", "--fleet", fleet, "--duration", "3", "-c", app, *wait)
    assert "robot0" in watch.stdout

    # The viewer identity may read the robots' frames (their poses): view and record.
    view = lessmap("view", "--fleet", fleet, "--port", "0", "--duration", "2", "-c", viewer, *wait)
    assert last_json(view)["fleet"] == fleet
    mcap = tmp_path / "fleet.mcap"
    lessmap("record", "--fleet", fleet, "--mcap", str(mcap), "--duration", "2", "-c", viewer, *wait)
    assert mcap.stat().st_size > 0

    # The ROS 2 bridge joins with a robot identity (no ROS topic here: it just runs).
    ros = lessmap("ros", "--fleet", fleet, "--duration", "1", "-c", robot, *wait)
    assert last_json(ros)["fleet"] == fleet

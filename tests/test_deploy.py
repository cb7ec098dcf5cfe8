"""The deploy folder stays true to the code: every setting is in the environment example,
the units run commands the CLI accepts, the router configs form a mesh, and the local cluster
script starts and stops a real site of two routers and three instances."""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import zenoh

from lessmap.cli.app import command_parser
from lessmap.config.settings import LimitSettings, ServiceSettings
from lessmap.runtime.router import router_config
from lessmap_client.session import open_session
from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.messages import Health
from lessmap_schemas.partition import PARTITIONS
from tests.conftest import wait_until

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"
ENV_EXAMPLE = DEPLOY / "lessmap.env.example"


def variables() -> list[str]:
    names = [f"LESSMAP_{n.upper()}" for n in ServiceSettings.model_fields if n != "limits"]
    names += [f"LESSMAP_LIMITS__{n.upper()}" for n in LimitSettings.model_fields]
    return names


@pytest.mark.parametrize("variable", variables())
def test_the_environment_example_lists_every_setting(variable: str) -> None:
    assert f"#{variable}=" in ENV_EXAMPLE.read_text(encoding="utf-8")


def test_the_environment_example_lists_no_setting_that_is_gone() -> None:
    listed = re.findall(r"^#(LESSMAP_\w+)=", ENV_EXAMPLE.read_text(encoding="utf-8"), re.M)
    assert set(listed) - {"LESSMAP_CONFIG"} <= set(variables())


# -- several instances: the router mesh, the template units, the local cluster script ----------


def json5(name: str) -> zenoh.Config:
    return zenoh.Config.from_file(str(DEPLOY / name))


def get(conf: zenoh.Config, key: str) -> Any:
    return json.loads(conf.get_json(key))


def test_the_two_routers_connect_to_each_other_on_named_addresses() -> None:
    a, b = json5("zenoh-router-a.json5"), json5("zenoh-router-b.json5")
    for name, conf in (("a", a), ("b", b)):
        assert get(conf, "mode") == "router", name
        assert get(conf, "scouting/multicast/enabled") is False, name
        text = (DEPLOY / f"zenoh-router-{name}.json5").read_text(encoding="utf-8")
        code = "\n".join(line.split("//")[0] for line in text.splitlines())
        assert "0.0.0.0" not in code
        assert "[::]" not in code
    assert get(a, "connect/endpoints") == get(b, "listen/endpoints")
    assert get(b, "connect/endpoints") == get(a, "listen/endpoints")
    # And `lessmap router -c` keeps them as they are.
    for name, conf in (("a", a), ("b", b)):
        built = router_config(DEPLOY / f"zenoh-router-{name}.json5")
        assert get(built, "listen/endpoints") == get(conf, "listen/endpoints")
        assert get(built, "connect/endpoints") == get(conf, "connect/endpoints")


def exec_start(unit: str) -> list[str]:
    """Return the arguments after ``lessmap`` of a unit's ExecStart, specifiers filled in."""
    text = (DEPLOY / unit).read_text(encoding="utf-8")
    line = next(ln for ln in text.splitlines() if ln.startswith("ExecStart="))
    argv = shlex.split(line.removeprefix("ExecStart=").replace("%i", "a").replace("%H", "host"))
    assert argv[0].endswith("/bin/lessmap"), line
    return argv[1:]


@pytest.mark.parametrize("unit", ["lessmap.service", "lessmap@.service", "lessmap-router@.service"])
def test_the_units_run_commands_the_cli_accepts(unit: str) -> None:
    command, *args = exec_start(unit)
    parser, _ = command_parser(command)
    parsed = parser.parse_args(args)
    if unit == "lessmap@.service":
        assert (parsed.mode, len(parsed.connect)) == ("client", 2)
        assert not getattr(parsed, "listen", None)  # a client listens nowhere
    if unit == "lessmap-router@.service":
        assert str(parsed.zenoh_config).endswith("zenoh-router-a.json5")


def test_each_templated_instance_has_its_own_name_and_state_directory() -> None:
    text = (DEPLOY / "lessmap@.service").read_text(encoding="utf-8")
    lines = text.splitlines()
    assert "Environment=LESSMAP_INSTANCE=%H-%i" in lines
    assert "Environment=LESSMAP_STATE_DIR=/var/lib/lessmap/%i" in lines
    assert "StateDirectory=lessmap/%i" in lines


@pytest.mark.timeout(180)
@pytest.mark.slow
def test_the_local_cluster_starts_two_routers_and_three_instances_and_stops_them(
    tmp_path: Path,
) -> None:
    folder = tmp_path / "cluster"
    env = {**os.environ, "LESSMAP": f"{sys.executable} -m lessmap"}
    script = str(DEPLOY / "local-cluster.sh")

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [script, *args, "--dir", str(folder)],
            env=env,
            capture_output=True,
            text=True,
            timeout=90,
            check=False,
        )

    started = run("start")
    pids = {p.stem: int(p.read_text()) for p in folder.glob("*.pid")}
    try:
        assert started.returncode == 0, started.stderr
        assert set(pids) == {"router-a", "router-b", "local-1", "local-2", "local-3"}
        assert "stop:" in started.stdout
        endpoints = dict(line.split() for line in (folder / "endpoints").read_text().splitlines())
        sessions = [open_session([endpoint], timeout_s=20.0) for endpoint in endpoints.values()]
        try:
            # Each router sees every instance (the mesh) ...
            expected = {keys.instance_token(f"local-{i}") for i in (1, 2, 3)}
            for session in sessions:
                wait_until(partial(sees, session, expected), 60.0, "the three instances' tokens")
            # ... and an instance killed -9 leaves both (its TCP link closes with it).
            os.kill(pids["local-2"], signal.SIGKILL)
            expected -= {keys.instance_token("local-2")}
            for session in sessions:
                wait_until(partial(sees, session, expected), 30.0, "local-2's token to go")
            # The survivors own every partition between them (their Health replies).
            wait_until(
                partial(owned_by, sessions[0], {"local-1", "local-3"}),
                60.0,
                f"local-1 and local-3 to own all {PARTITIONS} partitions",
            )
        finally:
            for session in sessions:
                session.close()
        stopped = run("stop")
        assert stopped.returncode == 0, stopped.stderr
        assert not any(alive(pid) for pid in pids.values())
        assert not list(folder.glob("*.pid"))
        for name in pids:
            assert "Traceback" not in (folder / f"{name}.log").read_text(), name
    finally:
        for pid in pids.values():  # whatever the test did, nothing it started outlives it
            if alive(pid):
                os.kill(pid, signal.SIGKILL)


def sees(session: zenoh.Session, expected: set[str]) -> bool:
    """Return whether the liveliness tokens of the instances are exactly ``expected``."""
    replies = session.liveliness().get(keys.instances(), timeout=1.0)
    return {str(r.ok.key_expr) for r in replies if r.ok is not None} == expected


def owned_by(session: zenoh.Session, instances: set[str]) -> bool:
    """Return whether exactly ``instances`` answer health and own the partitions."""
    owners: dict[int, list[str]] = {}
    answered = set()
    for reply in session.get(keys.health(), timeout=2.0):
        if reply.ok is None:
            continue
        health = decode(reply.ok.payload.to_bytes(), Health)
        answered.add(health.instance)
        for partition in health.partitions:
            owners.setdefault(partition, []).append(health.instance)
    return answered == instances and all(len(owners.get(p, [])) == 1 for p in range(PARTITIONS))


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state != "Z"

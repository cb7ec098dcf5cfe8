"""The pieces of ``serve --workers N``: names, folders, ports, the router, the worker file."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import TYPE_CHECKING

import pytest

from lessmap.config.settings import load_settings
from lessmap.errors import ConfigError
from lessmap.runtime.hub import gather_checkpoints, hub_config, serve_workers
from lessmap.runtime.record import SessionRecord
from lessmap.runtime.store import CheckpointStore
from lessmap.runtime.supervisor import LaunchSpec, RestartPolicy, Supervisor, describe_exit
from lessmap.runtime.workers import (
    WorkerRole,
    read_worker_file,
    usable_cores,
    worker_count,
    worker_name,
    worker_settings,
    write_worker_file,
)
from tests.conftest import free_port

if TYPE_CHECKING:
    from pathlib import Path


def test_the_default_is_one_worker_per_usable_core(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("LESSMAP_WORKERS")
    settings = load_settings()
    assert settings.workers is None
    assert worker_count(settings) == usable_cores() >= 1
    assert worker_count(load_settings(workers=3)) == 3


def test_each_worker_has_its_name_store_and_metrics_port(tmp_path: Path) -> None:
    settings = load_settings(instance="host-7", state_dir=tmp_path, metrics_port=9464)
    first, second = (worker_settings(settings, i, "tcp/127.0.0.1:7000") for i in (0, 1))
    assert (first.instance, second.instance) == ("host-7-w0", "host-7-w1")
    assert (first.state_dir, second.state_dir) == (tmp_path, tmp_path / "w1")
    assert (first.metrics_port, second.metrics_port) == (9464, 9465)
    assert second.mode == "client"
    assert second.connect == ("tcp/127.0.0.1:7000",)
    assert second.listen == ()
    assert second.workers == 1
    assert worker_settings(load_settings(metrics_port=0), 1, None).metrics_port == 0
    assert len(worker_name("x" * 64, 12)) == 64


def test_a_client_service_has_no_hub_and_a_router_keeps_its_loopback_endpoint() -> None:
    client = load_settings(mode="client", connect=("tcp/127.0.0.1:7447",))
    assert hub_config(client, ()) is None
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = hub_config(load_settings(mode="router", listen=(endpoint,)), ())
    assert hub is not None
    assert hub.endpoint == endpoint
    embedded = hub_config(load_settings(), ())
    assert embedded is not None
    assert embedded.endpoint == "tcp/127.0.0.1:7447"


def test_a_peer_becomes_the_router_with_a_loopback_endpoint_for_its_workers() -> None:
    hub = hub_config(load_settings(mode="peer", listen=("tcp/0.0.0.0:7450",)), ())
    assert hub is not None
    assert json.loads(hub.config.get_json("mode")) == "router"
    assert hub.endpoint.startswith("tcp/127.0.0.1:")
    assert json.loads(hub.config.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7450", hub.endpoint]


def test_with_a_private_folder_the_workers_meet_on_a_unix_socket(tmp_path: Path) -> None:
    hub = hub_config(load_settings(), (), tmp_path)
    assert hub is not None
    assert hub.endpoint == f"unixsock-stream/{tmp_path / 'hub.sock'}"
    assert json.loads(hub.config.get_json("listen/endpoints")) == [
        "tcp/127.0.0.1:7447",
        hub.endpoint,
    ]
    assert hub.worker_cfg == ()
    # no access control: none is added
    assert json.loads(hub.config.get_json("access_control"))["enabled"] is False


def test_a_secured_hub_lets_its_socket_in_and_hands_the_workers_its_user(tmp_path: Path) -> None:
    rule = {"id": "r", "permission": "allow", "messages": ["put"], "flows": ["ingress"],
            "key_exprs": ["a/**"]}  # fmt: skip
    access = {"enabled": True, "default_permission": "deny", "rules": [rule],
              "subjects": [{"id": "s", "interfaces": ["lo"]}],
              "policies": [{"rules": ["r"], "subjects": ["s"]}]}  # fmt: skip
    cfg = [
        f"access_control:{json.dumps(access)}",
        'transport/auth/usrpwd/user:"svc"',
        'transport/auth/usrpwd/password:"pw"',
    ]
    hub = hub_config(load_settings(), cfg, tmp_path)
    assert hub is not None
    merged = json.loads(hub.config.get_json("access_control"))
    assert merged["default_permission"] == "deny"
    assert [s["id"] for s in merged["subjects"]] == ["s", "lessmap-workers"]
    assert merged["subjects"][1]["link_protocols"] == ["unixsock-stream"]
    assert merged["policies"][1]["subjects"] == ["lessmap-workers"]
    assert "lessmap/v4/@/**" in merged["rules"][1]["key_exprs"]
    assert hub.worker_cfg == (
        'transport/auth/usrpwd/user:"svc"',
        'transport/auth/usrpwd/password:"pw"',
    )


def test_the_worker_file_carries_the_whole_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = load_settings(instance="a-w1", state_dir=tmp_path, shards=3, method="paper")
    path = tmp_path / "w1.json"
    write_worker_file(path, WorkerRole(1, 42, 7), settings, ["a:1"])
    assert path.stat().st_mode & 0o077 == 0
    monkeypatch.setenv("LESSMAP_SHARDS", "5")  # the parent read the environment already
    role, again, cfg = read_worker_file(path)
    assert (role, role.tag, cfg) == (WorkerRole(1, 42, 7), "w1", ["a:1"])
    assert again == settings
    path.write_text("{}", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"w1\.json"):
        read_worker_file(path)


def record(robot: str, seq: int) -> SessionRecord:
    return SessionRecord(
        fleet="f",
        robot=robot,
        session="s1",
        status="open",
        last_seq=seq,
        meta={"epoch": 1},
        snapshot=b"x",
        updated_s=time.time(),
    )


def test_worker_stores_are_gathered_into_worker_0s(tmp_path: Path) -> None:
    stores = {0: tmp_path, 1: tmp_path / "w1", 3: tmp_path / "w3"}
    held = {0: [record("a", 5)], 1: [record("a", 9), record("b", 3)]}
    held[3] = [record("c", 1)]  # a run with more workers left it
    for index, folder in stores.items():
        store = CheckpointStore(folder)
        store.open()
        for r in held[index]:
            store.save(r)
        store.close()
    assert gather_checkpoints(load_settings(state_dir=tmp_path), 2) == 3
    store = CheckpointStore(tmp_path)
    store.open()
    try:
        assert {(r.robot, r.last_seq) for r in store.records()} == {("a", 9), ("b", 3), ("c", 1)}
    finally:
        store.close()


def test_a_store_in_use_is_one_line(tmp_path: Path) -> None:
    busy = CheckpointStore(tmp_path / "w1")
    busy.open()
    try:
        with pytest.raises(ConfigError, match="in use"):
            gather_checkpoints(load_settings(state_dir=tmp_path), 2)
    finally:
        busy.close()


def test_exits_are_described() -> None:
    assert describe_exit(-9) == "was killed by SIGKILL"
    assert describe_exit(1) == "exited with code 1"
    assert RestartPolicy().max_restarts >= 1


def test_a_worker_that_cannot_start_stops_the_service(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        args = [sys.executable, "-m", "lessmap", "serve", "--workers", "2", "-m", "router"]
        args += ["-l", f"tcp/127.0.0.1:{free_port()}", "--state-dir", str(tmp_path)]
        args += ["--metrics-port", str(port), "--cfg", "scouting/multicast/enabled:false"]
        done = subprocess.run(args, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 1, done.stderr
    assert re.search(r"worker w\d exited with code 1 before it served", done.stderr)
    assert "lessmap serve: " in done.stderr  # the worker's own one-line reason
    assert "Traceback" not in done.stderr


def test_a_worker_dying_past_the_restart_budget_stops_the_supervisor(tmp_path: Path) -> None:
    settings = load_settings(
        mode="router",
        listen=(f"tcp/127.0.0.1:{free_port()}",),
        memory_only=True,
        instance="budget",
    )
    folder = tmp_path / "files"
    folder.mkdir()
    zenoh_cfg = ("scouting/multicast/enabled:false",)
    supervisor = Supervisor(
        [worker_settings(settings, 0, None)],
        LaunchSpec(folder, zenoh_cfg=zenoh_cfg),
        RestartPolicy(max_restarts=0, ready_timeout_s=60.0, stop_timeout_s=20.0),
    )
    stop = threading.Event()
    try:
        assert supervisor.start(stop)
        process = supervisor.slots[0].process
        assert process is not None
        os.kill(process.pid, signal.SIGKILL)
        timer = threading.Timer(30.0, stop.set)  # a bound on the wait: never reached
        timer.start()
        assert supervisor.watch(stop) is False
        timer.cancel()
        assert not stop.is_set()
    finally:
        supervisor.stop()
    assert supervisor.slots[0].process is None


def test_metrics_ports_past_the_last_port_are_one_line() -> None:
    settings = load_settings(metrics_port=65535, workers=2, memory_only=True)
    with pytest.raises(ConfigError, match="ports up to 65536"):
        serve_workers(settings)


def test_a_router_that_checks_users_but_has_none_of_its_own_is_refused(tmp_path: Path) -> None:
    dictionary = tmp_path / "users.txt"
    dictionary.write_text("robot:secret\n")
    cfg = [f"transport/auth/usrpwd/dictionary_file:{json.dumps(str(dictionary))}"]
    with pytest.raises(ConfigError, match="workers need the configuration's own user"):
        hub_config(load_settings(), cfg, tmp_path)

"""``lessmap router``: a real router process that real Zenoh clients (and routers) join."""

from __future__ import annotations

import contextlib
import json
import signal
import socket
import subprocess
import sys
from typing import TYPE_CHECKING

import pytest

from lessmap.runtime.router import router_config
from lessmap_client.session import open_session
from tests.conftest import free_port, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    import zenoh

pytestmark = pytest.mark.timeout(90)


class RouterProcess:
    """One ``python -m lessmap router`` process, its stderr in a file."""

    def __init__(self, log_path: Path, *args: str) -> None:
        self.log_path = log_path
        with log_path.open("wb") as log_file:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "lessmap", "router", *args],
                stdout=log_file,
                stderr=log_file,
            )

    def log(self) -> str:
        return self.log_path.read_text(encoding="utf-8", errors="replace")

    def wait_listening(self) -> None:
        wait_until(
            lambda: "router listening on" in self.log() or self.process.poll() is not None,
            30.0,
            "the router to listen",
        )
        assert self.process.poll() is None, self.log()

    def terminate(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(15)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(5)
            raise


@pytest.fixture
def router(tmp_path: Path) -> Iterator[Callable[..., RouterProcess]]:
    """Start router processes; each is stopped by its PID at teardown."""
    started: list[RouterProcess] = []

    def start(*args: str) -> RouterProcess:
        proc = RouterProcess(tmp_path / f"router-{len(started)}.log", *args)
        started.append(proc)
        return proc

    yield start
    for proc in started:
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.terminate()


@pytest.fixture
def sessions() -> Iterator[Callable[[str], zenoh.Session]]:
    """Open client sessions; all are closed at teardown."""
    opened: list[zenoh.Session] = []

    def open_to(endpoint: str) -> zenoh.Session:
        session = open_session([endpoint], timeout_s=20.0)
        opened.append(session)
        return session

    yield open_to
    for session in reversed(opened):
        session.close()


def exchange(publisher: zenoh.Session, subscriber: zenoh.Session, key: str) -> list[bytes]:
    """Put on ``key`` until the subscriber got one sample (declarations take a moment)."""
    got: list[bytes] = []
    sub = subscriber.declare_subscriber(key, lambda sample: got.append(sample.payload.to_bytes()))

    def delivered() -> bool:
        if not got:
            publisher.put(key, b"hello")
        return bool(got)

    try:
        wait_until(delivered, 20.0, f"a put on {key} to reach the other client")
    finally:
        sub.undeclare()
    return got


def test_two_clients_exchange_through_the_router_and_sigterm_exits_0(
    router: Callable[..., RouterProcess], sessions: Callable[[str], zenoh.Session]
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = router("-l", endpoint)
    proc.wait_listening()
    assert f"router listening on {endpoint}" in proc.log()
    first, second = sessions(endpoint), sessions(endpoint)
    assert set(exchange(first, second, "lessmap-test/router/a")) == {b"hello"}
    assert set(exchange(second, first, "lessmap-test/router/b")) == {b"hello"}
    assert proc.terminate() == 0, proc.log()
    assert "Traceback" not in proc.log()


def test_two_routers_form_a_mesh(
    router: Callable[..., RouterProcess], sessions: Callable[[str], zenoh.Session]
) -> None:
    a = f"tcp/127.0.0.1:{free_port()}"
    b = f"tcp/127.0.0.1:{free_port()}"
    first = router("-l", a)
    first.wait_listening()
    second = router("-l", b, "-e", a)
    second.wait_listening()
    assert f"connecting to {a}" in second.log()
    on_a, on_b = sessions(a), sessions(b)
    assert set(exchange(on_b, on_a, "lessmap-test/mesh/ab")) == {b"hello"}
    assert set(exchange(on_a, on_b, "lessmap-test/mesh/ba")) == {b"hello"}
    assert second.terminate() == 0, second.log()
    assert first.terminate() == 0, first.log()


def test_a_taken_port_is_one_line_and_exit_1(router: Callable[..., RouterProcess]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = router("-l", f"tcp/127.0.0.1:{port}")
        assert proc.process.wait(30) == 1, proc.log()
    lines = proc.log().strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("lessmap router: "), lines
    assert f"tcp/127.0.0.1:{port}" in lines[0]
    assert "already in use" in lines[0]
    assert "-l/--listen" in lines[0]  # which flag to change


def test_a_bad_config_is_one_line_and_exit_1(
    router: Callable[..., RouterProcess], tmp_path: Path
) -> None:
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 'router', listen: { endpoints: 5 } }")
    for args in (["-c", str(bad)], ["--zenoh-config", str(tmp_path / "missing.json5")]):
        proc = router(*args)
        assert proc.process.wait(30) == 1, proc.log()
        lines = proc.log().strip().splitlines()
        assert len(lines) == 1, lines
        assert lines[0].startswith("lessmap router: "), lines
        assert ".rs:" not in lines[0]


def test_the_old_config_spelling_still_works_and_says_so(
    router: Callable[..., RouterProcess], tmp_path: Path
) -> None:
    proc = router("--config", str(tmp_path / "missing.json5"))
    assert proc.process.wait(30) == 1, proc.log()
    assert proc.log().strip().splitlines() == [
        "lessmap router: --config is deprecated; use -c/--zenoh-config",
        f"lessmap router: Zenoh config {tmp_path / 'missing.json5'}: no such file",
    ]


def test_a_config_file_keeps_its_endpoints_and_scouting_stays_off(tmp_path: Path) -> None:
    plain = router_config(None)
    assert json.loads(plain.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(plain.get_json("scouting/multicast/enabled")) is False
    assert json.loads(plain.get_json("mode")) == "router"
    conf_file = tmp_path / "r.json5"
    conf_file.write_text('{ listen: { endpoints: ["tcp/127.0.0.1:17001"] } }')
    from_file = router_config(conf_file, connect=["tcp/127.0.0.1:17002"])
    assert json.loads(from_file.get_json("listen/endpoints")) == ["tcp/127.0.0.1:17001"]
    assert json.loads(from_file.get_json("connect/endpoints")) == ["tcp/127.0.0.1:17002"]
    assert json.loads(from_file.get_json("scouting/multicast/enabled")) is False
    conf_file.write_text("{ scouting: { multicast: { enabled: true } } }")
    asks = router_config(conf_file, listen=["tcp/127.0.0.1:17003"])
    assert json.loads(asks.get_json("scouting/multicast/enabled")) is True
    assert json.loads(asks.get_json("listen/endpoints")) == ["tcp/127.0.0.1:17003"]

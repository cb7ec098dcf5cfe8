"""Shared fixtures: free loopback ports, a real ``lessmap serve`` subprocess, data paths."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.messages import SessionState

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    import zenoh

REPO = Path(__file__).resolve().parents[1]
DATASETS = REPO / ".." / "shared" / "datasets"


def dataset(name: str) -> Path:
    """Return a shared data set's path, or skip the test with the reason."""
    path = DATASETS / name
    if not path.exists():
        pytest.skip(f"data set {name} not found under ../shared/datasets (not in this checkout)")
    return path


def free_port() -> int:
    """Return a TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


@pytest.fixture
def endpoint() -> str:
    """A fresh loopback Zenoh endpoint."""
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def fleet_name() -> str:
    """A fleet name no other test uses."""
    return f"test-{uuid.uuid4().hex[:10]}"


@dataclass
class ServeProcess:
    """A real ``lessmap serve`` process on a loopback router endpoint."""

    endpoint: str
    process: subprocess.Popen[bytes]
    log_path: Path
    instance: str
    metrics_port: int | None = None
    extra: list[str] = field(default_factory=list)

    def log(self) -> str:
        """Return what the service wrote on stderr so far."""
        return self.log_path.read_text(encoding="utf-8", errors="replace")

    def terminate(self, timeout_s: float = 10.0) -> int:
        """Send SIGTERM and wait; return the exit code (kills by PID after the timeout)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(5)
            raise

    def rss_kib(self) -> int:
        """Return the resident memory of the service process."""
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        return 0

    def metrics(self) -> str:
        """Return the Prometheus text exposition of the service."""
        import urllib.request

        assert self.metrics_port is not None, "start the service with metrics=True"
        url = f"http://127.0.0.1:{self.metrics_port}/metrics"
        with urllib.request.urlopen(url, timeout=5) as response:
            text: str = response.read().decode()
        return text


def metric_value(text: str, name: str, **labels: str) -> float:
    """Return one sample's value from a Prometheus text exposition (0 when absent)."""
    wanted = name
    if labels:
        inner = ",".join(f'{k}="{v}"' for k, v in sorted(labels.items()))
        wanted = f"{name}{{{inner}}}"
    for line in text.splitlines():
        if line.startswith(wanted + " "):
            return float(line.rsplit(" ", 1)[1])
    return 0.0


@pytest.fixture(autouse=True)
def private_state_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Every ``lessmap serve`` a test starts keeps its session checkpoints under tmp_path.

    And runs as one process (``LESSMAP_WORKERS=1``) unless the test gives ``--workers``.

    The default state directory is under ``$XDG_STATE_HOME``: without this, tests would
    share (and resume) each other's sessions and write into the user's home.
    """
    folder = tmp_path / "xdg-state"
    monkeypatch.setenv("XDG_STATE_HOME", str(folder))
    # One process per ``lessmap serve`` unless a test asks for workers (tests of
    # ``--workers N`` do): what the other tests observe is one instance.
    monkeypatch.setenv("LESSMAP_WORKERS", "1")
    monkeypatch.delenv("LESSMAP_STATE_DIR", raising=False)
    monkeypatch.delenv("LESSMAP_MEMORY_ONLY", raising=False)
    return folder


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[Callable[..., ServeProcess]]:
    """Start ``lessmap serve`` subprocesses; every one is stopped by PID at teardown."""
    started: list[ServeProcess] = []

    def start(
        *extra: str, metrics: bool = False, env: dict[str, str] | None = None
    ) -> ServeProcess:
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        instance = f"test-{uuid.uuid4().hex[:8]}"
        args = [
            sys.executable,
            "-m",
            "lessmap",
            "-v",
            "serve",
            "-m",
            "router",
            "-l",
            endpoint,
            "--cfg",
            "scouting/multicast/enabled:false",
            "--instance",
            instance,
        ]
        metrics_port = None
        if metrics:
            metrics_port = free_port()
            args += ["--metrics-port", str(metrics_port)]
        args += list(extra)
        log_path = tmp_path / f"serve-{instance}.log"
        full_env = {**os.environ, **(env or {})}
        with log_path.open("wb") as log_file:
            process = subprocess.Popen(args, stdout=log_file, stderr=log_file, env=full_env)
        proc = ServeProcess(endpoint, process, log_path, instance, metrics_port, list(extra))
        started.append(proc)
        return proc

    yield start
    for proc in started:
        if proc.process.poll() is None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.terminate(timeout_s=10.0)


@pytest.fixture
def client_session() -> Iterator[Callable[[str], zenoh.Session]]:
    """Open client sessions to an endpoint; all are closed at teardown."""
    from lessmap_client.session import open_session

    sessions: list[zenoh.Session] = []

    def open_to(target: str) -> zenoh.Session:
        session = open_session([target], timeout_s=20.0)
        sessions.append(session)
        return session

    yield open_to
    for session in sessions:
        session.close()


def wait_until(
    predicate: Callable[[], bool], timeout_s: float, what: str, why: Callable[[], str] | None = None
) -> None:
    """Poll ``predicate`` until it holds; fail the test naming ``what`` after the timeout.

    ``why`` is called on a timeout only, for what the failure should show (logs, a state).
    """
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() >= deadline:
            detail = f"\n{why()}" if why is not None else ""
            msg = f"timed out after {timeout_s} s waiting for {what}{detail}"
            raise AssertionError(msg)
        time.sleep(0.05)


@pytest.fixture
def router() -> Iterator[str]:
    """A plain Zenoh router in the test process, on a free loopback port; its endpoint.

    Service processes join it, so they can die and restart while robots and fleet apps stay
    connected; client tests play the service's part on it with sessions of their own.
    """
    import json

    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    with zenoh.open(conf):
        yield endpoint


def new_robot_wait_s(
    session: zenoh.Session, fleet: str, robot: str, frame: bytes, timeout_s: float
) -> float:
    """Put a new robot's first frame; seconds until a state query shows it applied (or NaN).

    The state query is asked every 10 ms, so the figure is within ~10 ms of the service's.
    """
    key = keys.state(fleet, robot)
    start = time.monotonic()
    session.put(keys.frames(fleet, robot), frame, congestion_control=zenoh.CongestionControl.BLOCK)
    while time.monotonic() - start < timeout_s:
        for reply in session.get(key, timeout=2.0):
            if reply.ok is not None:
                state = decode(reply.ok.payload.to_bytes(), SessionState)
                if state.frames_applied >= 1:
                    return time.monotonic() - start
        time.sleep(0.01)
    return float("nan")

"""Processes and measurements of the fleet load benchmark: the service, /proc, samplers, py-spy.

Every process is started on 127.0.0.1 and stopped by its PID (SIGTERM, then kill). The
offline baseline times the core alone, in this process, on the same streams.
"""

from __future__ import annotations

import contextlib
import http.client
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from benchmarks.fleet.profile_summary import summarize_profile

if TYPE_CHECKING:
    from collections.abc import Callable

    from benchmarks.fleet.loadgen import LoadSpec
    from lessmap_client import FleetClient

_SAMPLE_PERIOD_S = 0.5  # RSS and CPU samples
_CLK_TCK = os.sysconf("SC_CLK_TCK")


# -- processes and /proc -----------------------------------------------------------------------


def free_port() -> int:
    """Return a TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


def free_ports(count: int) -> int:
    """The first of ``count`` consecutive TCP ports on 127.0.0.1 that were free a moment ago."""
    while True:
        first = free_port()
        with contextlib.ExitStack() as held:
            try:
                for port in range(first + 1, first + count):
                    sock = held.enter_context(socket.socket())
                    sock.bind(("127.0.0.1", port))
            except OSError:
                continue
        return first


def stop_process(process: subprocess.Popen[bytes], timeout_s: float = 20.0) -> int | None:
    """SIGTERM one process by its PID, wait, then kill it; close its pipes; return its code."""
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(10)
    for stream in (process.stdin, process.stdout, process.stderr):
        if stream is not None:
            stream.close()
    return process.returncode


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (/proc/PID/stat fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _CLK_TCK


def thread_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds of a process's threads, summed by thread name (/proc/PID/task/*/stat).

    Python threads keep the interpreter's name (``python``); Zenoh's runtime threads carry
    their own (``rx-0``, ``tx-0``, ``net-0``, ...), so this splits Python from Rust work.
    """
    by_name: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError, ValueError, IndexError):
            text = (task / "stat").read_text()
            name = text[text.index("(") + 1 : text.rindex(")")]
            fields = text.rsplit(")", 1)[1].split()
            name = re.sub(r"[-_]?\d+$", "", name) or name  # rx-0, rx-1 -> rx
            cpu = (int(fields[11]) + int(fields[12])) / _CLK_TCK
            by_name[name] = by_name.get(name, 0.0) + cpu
    return dict(sorted(by_name.items(), key=lambda item: -item[1]))


def proc_status_kib(pid: int, key: str) -> int:
    """A ``kB`` field of /proc/PID/status (VmRSS, VmHWM), 0 when absent."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1])
    return 0


def socket_bytes(port: int) -> dict[str, tuple[int, int]]:
    """Bytes received and sent per TCP connection whose local port is ``port`` (``ss``).

    Keyed by the peer's address; empty without ``ss``.
    """
    exe = shutil.which("ss")
    if exe is None:
        return {}
    out = subprocess.run(
        [exe, "-tinH", "state", "established", f"( sport = :{port} )"],
        capture_output=True,
        text=True,
        timeout=10,
        check=False,
    ).stdout
    found: dict[str, tuple[int, int]] = {}
    peer = ""
    for line in out.splitlines():
        if not line[:1].isspace():  # the socket line: Recv-Q Send-Q local peer
            fields = line.split()
            peer = fields[-1] if fields else ""
            continue
        received = re.search(r"\bbytes_received:(\d+)", line)
        sent = re.search(r"\bbytes_sent:(\d+)", line)
        found[peer] = (int(received[1]) if received else 0, int(sent[1]) if sent else 0)
    return found


@dataclass(slots=True)
class SocketMeter:
    """TCP bytes through a router's port while the load runs (every half second, ``ss``).

    Per connection, the last reading minus the first (0 for one opened later), so the
    generators' connections count even after they closed. On one host Zenoh moves payloads
    above 3 KiB (checkpoints) through shared memory by default: they are not in these bytes.
    """

    port: int
    first: dict[str, tuple[int, int]] = field(default_factory=dict)
    last: dict[str, tuple[int, int]] = field(default_factory=dict)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def start(self) -> None:
        """Take the first reading and keep reading on a thread."""
        self.first = socket_bytes(self.port)
        self.last = dict(self.first)
        self._thread = threading.Thread(target=self._run, name="bench-sockets", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(_SAMPLE_PERIOD_S):
            with contextlib.suppress(OSError, subprocess.SubprocessError):
                self.last.update(socket_bytes(self.port))

    def stop(self) -> tuple[int, int]:
        """Stop; return (bytes received, bytes sent) by the router during the run."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(15.0)
        with contextlib.suppress(OSError, subprocess.SubprocessError):
            self.last.update(socket_bytes(self.port))
        received = sum(r - self.first.get(p, (0, 0))[0] for p, (r, _) in self.last.items())
        sent = sum(s - self.first.get(p, (0, 0))[1] for p, (_, s) in self.last.items())
        return received, sent


def load_average() -> tuple[float, float, float]:
    """The 1, 5 and 15 minute load averages."""
    one, five, fifteen = Path("/proc/loadavg").read_text().split()[:3]
    return float(one), float(five), float(fifteen)


class RouterProcess:
    """``python -m lessmap router`` on a fresh loopback port (no service in it)."""

    def __init__(self, log_path: Path) -> None:
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.log_path = log_path
        args = [sys.executable, "-m", "lessmap", "router", "-l", self.endpoint]
        with log_path.open("wb") as log:
            self.process = subprocess.Popen(args, stdout=log, stderr=log)

    @property
    def pid(self) -> int:
        """The router's PID."""
        return self.process.pid

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        """Wait until the router accepts TCP connections on its port."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.process.poll() is not None:
                msg = f"lessmap router exited with {self.process.returncode}: {self.log_tail()}"
                raise RuntimeError(msg)
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1.0):
                    return
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def log_tail(self, lines: int = 20) -> str:
        """The last lines the router logged."""
        text = self.log_path.read_text(encoding="utf-8", errors="replace")
        return "\n".join(text.splitlines()[-lines:])


class ServiceProcess:
    """``python -m lessmap serve`` with metrics, on loopback.

    Alone (``connect`` None) it is its own router on a fresh port, as in a one-instance
    deployment. Joined (``connect`` a router's endpoint) it is a Zenoh client of that
    router, as the instances of a multi-instance site are. Either way it has its own
    instance name (``bench-<our pid>-<index>``) and its own state directory.
    """

    def __init__(
        self, spec: LoadSpec, log_path: Path, index: int = 0, connect: str | None = None
    ) -> None:
        self.index = index
        # `--workers N` serves metrics on N ports from this one: all of them free.
        self.metrics_port = free_ports(spec.serve_workers)
        self.instance = f"bench-{os.getpid()}-{index}"
        args = [sys.executable, "-m", "lessmap", "serve"]
        if connect is None:
            self.endpoint = f"tcp/127.0.0.1:{free_port()}"
            args += ["-m", "router", "-l", self.endpoint]
        else:
            self.endpoint = connect  # where robots and apps reach this instance
            args += ["-m", "client", "-e", connect]
        args += [
            "--cfg",
            "scouting/multicast/enabled:false",
            "--metrics-port",
            str(self.metrics_port),
            "--instance",
            self.instance,
        ]
        if spec.shards is not None:
            args += ["--shards", str(spec.shards)]
        # Always given: the service's own default is one worker per core.
        args += ["--workers", str(spec.serve_workers)]
        if spec.max_batch_frames is not None:
            args += ["--max-batch-frames", str(spec.max_batch_frames)]
        if spec.batch_linger_ms is not None:
            args += ["--batch-linger-ms", str(spec.batch_linger_ms)]
        if spec.method is not None:
            args += ["--method", spec.method]
        # Checkpoints go to the run's own folder (one per instance), never to the user's.
        args += (
            ["--memory-only"]
            if spec.memory_only
            else ["--state-dir", str(log_path.parent / f"state-{index}")]
        )
        self.log_path = log_path
        with log_path.open("wb") as log:
            self.process = subprocess.Popen(args, stdout=log, stderr=log)

    @property
    def pid(self) -> int:
        """The service's PID."""
        return self.process.pid

    def metrics_text(self) -> str:
        """The Prometheus exposition of the service."""
        url = f"http://127.0.0.1:{self.metrics_port}/metrics"
        with urllib.request.urlopen(url, timeout=10) as response:
            text: str = response.read().decode()
        return text

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        """Wait until the metrics endpoint answers (the service has declared everything)."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.process.poll() is not None:
                msg = f"lessmap serve exited with {self.process.returncode}: {self.log_tail()}"
                raise RuntimeError(msg)
            try:
                self.metrics_text()
                return
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def kill9(self) -> float:
        """SIGKILL the service by its PID (no hand-over, no final checkpoint); return when."""
        self.process.send_signal(signal.SIGKILL)
        at = time.time()
        self.process.wait(10)
        return at

    def log_tail(self, lines: int = 20) -> str:
        """The last lines the service logged."""
        text = self.log_path.read_text(encoding="utf-8", errors="replace")
        return "\n".join(text.splitlines()[-lines:])


class _ByPid:
    """``poll()`` of a process this one did not start (a worker of ``serve --workers N``)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid

    def poll(self) -> int | None:
        try:
            stat = Path(f"/proc/{self.pid}/stat").read_text()
        except OSError:
            return -9
        return -9 if stat.rpartition(")")[2].split()[0] in {"Z", "X"} else None


class WorkerView:
    """One worker of a ``serve --workers N`` parent, seen as an instance of its own.

    Its name is the parent's instance plus ``-w<index>``, its metrics port the parent's plus
    the index; its PID comes from /proc once the parent has started it.
    """

    def __init__(self, parent: ServiceProcess, index: int) -> None:
        self.parent = parent
        self.index = index
        self.instance = f"{parent.instance}-w{index}"
        self.metrics_port = parent.metrics_port + index
        self.endpoint = parent.endpoint
        self.log_path = parent.log_path
        self._pid: int | None = None

    @property
    def pid(self) -> int:
        """The worker's PID (its worker file is named ``w<index>.json``)."""
        if self._pid is None:
            tag = f"w{self.index}.json".encode()
            for child in _children(self.parent.pid):
                with contextlib.suppress(OSError):
                    if any(
                        a.endswith(tag)
                        for a in Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
                    ):
                        self._pid = child
            if self._pid is None:
                msg = f"worker {self.instance} has no process: {self.parent.log_tail()}"
                raise RuntimeError(msg)
        return self._pid

    @property
    def process(self) -> _ByPid:
        """The worker's process, polled through /proc."""
        return _ByPid(self.pid)

    def metrics_text(self) -> str:
        """The Prometheus exposition of the worker."""
        url = f"http://127.0.0.1:{self.metrics_port}/metrics"
        with urllib.request.urlopen(url, timeout=10) as response:
            text: str = response.read().decode()
        return text

    def wait_ready(self, timeout_s: float = 90.0) -> None:
        """Wait until the worker's metrics endpoint answers."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.parent.process.poll() is not None:
                msg = f"lessmap serve exited with {self.parent.process.returncode}"
                raise RuntimeError(msg + ": " + self.parent.log_tail())
            try:
                self.metrics_text()
                return
            except (OSError, http.client.HTTPException):
                # HTTPException: before the worker listens, a connection to the free port
                # can meet itself (a TCP self-connect) and read its own request back.
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def kill9(self) -> float:
        """SIGKILL the worker by its PID (its parent starts it again); return when."""
        os.kill(self.pid, signal.SIGKILL)
        at = time.time()
        deadline = time.monotonic() + 10.0
        while self.process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        return at

    def log_tail(self, lines: int = 20) -> str:
        """The last lines of the parent's log (the workers write to it too)."""
        return self.parent.log_tail(lines)


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def stop_all(processes: list[subprocess.Popen[bytes]], timeout_s: float = 30.0) -> list[int | None]:
    """SIGTERM every process still running at once, then wait for each (kill after the timeout).

    Instances stopped one by one would hand their partitions to each other in turn. Each
    gets one SIGTERM only: a second one during its shutdown would end it with -15.
    """
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    codes: list[int | None] = []
    for process in processes:
        try:
            process.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(10)
        codes.append(stop_process(process))  # closes the pipes; the process has exited
    return codes


@dataclass(slots=True)
class Sampler:
    """Samples the service's RSS and CPU every half second on a thread."""

    pid: int
    extra_pids: list[int] = field(default_factory=list)  # more service processes, summed
    t0: float = 0.0
    samples: list[tuple[float, int, float]] = field(default_factory=list)  # (s, KiB, CPU s)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def start(self, t0: float) -> None:
        """Sample from now on; times are relative to ``t0`` (Unix seconds)."""
        self.t0 = t0
        self._thread = threading.Thread(target=self._run, name="bench-sampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last_cpu: dict[int, float] = {}  # a process killed mid-run keeps its last CPU reading
        while not self._stop.wait(_SAMPLE_PERIOD_S):
            rss = 0
            for pid in [self.pid, *self.extra_pids]:
                with contextlib.suppress(OSError, ValueError):
                    rss += proc_status_kib(pid, "VmRSS")
                    last_cpu[pid] = proc_cpu_s(pid)
            self.samples.append((time.time() - self.t0, rss, sum(last_cpu.values())))

    def stop(self) -> None:
        """Stop sampling."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)


@dataclass(slots=True)
class TransitionLog:
    """Receipt time of every transition a ``FleetClient`` gets, on a thread."""

    client: FleetClient
    received: list[tuple[str, int, int, float]] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def start(self) -> None:
        """Start receiving."""
        self._thread = threading.Thread(target=self._run, name="bench-transitions", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            transition = self.client.next_transition(timeout_s=0.2)
            if transition is None:
                if self._stop.is_set():
                    return  # stopped and nothing left to take
                continue
            self.received.append(
                (transition.robot, transition.seq, transition.batch_frames, time.time())
            )

    def wait_for(self, count: int, timeout_s: float) -> None:
        """Wait until ``count`` transitions arrived (or ``timeout_s`` passed)."""
        deadline = time.monotonic() + timeout_s
        while len(self.received) < count and time.monotonic() < deadline:
            time.sleep(0.05)

    def stop(self) -> None:
        """Stop receiving once the queue is empty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10.0)


# -- profile ---------------------------------------------------------------------------------


def pyspy_path() -> str | None:
    """The py-spy executable ``--profile`` runs (on PATH or beside this Python), if any."""
    beside = Path(sys.executable).with_name("py-spy")
    return shutil.which("py-spy") or (str(beside) if beside.is_file() else None)


def _start_pyspy(pid: int, out: Path, duration_s: float) -> subprocess.Popen[bytes]:
    exe = pyspy_path() or "py-spy"
    fmt = "flamegraph" if out.suffix == ".svg" else "raw"
    args = [
        exe,
        "record",
        "--pid",
        str(pid),
        "--duration",
        str(round(duration_s)),
        "--rate",
        "100",
        "--nonblocking",  # never pause the service: its latency is what is measured
        "--gil",  # shards share one GIL: a thread waiting for it is not where time goes
        "--threads",
        "--format",
        fmt,
        "-o",
        str(out),
    ]
    return subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _finish_pyspy(
    process: subprocess.Popen[bytes],
    out: Path | None,
    duration_s: float,
    say: Callable[[str], None],
) -> None:
    try:
        process.wait(duration_s + 30.0)
    except subprocess.TimeoutExpired:
        stop_process(process)
    if out is not None and out.suffix != ".svg" and out.exists():
        summary = summarize_profile(out.read_text(encoding="utf-8"))
        out.with_suffix(".summary.txt").write_text(summary, encoding="utf-8")
        say(f"profile: {out} (summary {out.with_suffix('.summary.txt')})")


# -- offline baseline ---------------------------------------------------------------------------


def offline_baseline(
    streams: list[list[list[int]]], frames_per_decision: float, method: str | None = None
) -> tuple[float, float, float, int]:
    """Time the core alone on streams: (observe, apply, coalesced) µs per frame, frames.

    One thread (BLAS limited to one, as the service runs it); robots interleaved frame by
    frame as the service sees them. Timed with the thread's CPU clock, as the service's side
    is with its process's: wall time counted whatever else the shared machine ran meanwhile.
    """
    from threadpoolctl import threadpool_limits

    from lessmap.core import PartitionParams
    from lessmap.core.segmenter import DEFAULT_METHOD, make_segmenter

    # The service's method (``serve --method``), through the segmenter a session drives:
    # a service running ``areas`` measured against the paper's core would flatter neither.
    # None is the service's default, as ``LoadSpec.method`` None runs ``serve`` without one.
    chosen = method or DEFAULT_METHOD
    params = PartitionParams.from_profile("laser")
    frames = sum(len(s) for s in streams)
    every = max(1, round(frames_per_decision)) if not math.isnan(frames_per_decision) else 1
    timings: list[float] = []
    with threadpool_limits(limits=1):
        for mode in ("observe", "apply", "coalesced"):
            segmenters = [make_segmenter(chosen, params) for _ in streams]
            started = time.thread_time()
            for k in range(max((len(s) for s in streams), default=0)):
                for stream, segmenter in zip(streams, segmenters, strict=True):
                    if k >= len(stream):
                        continue
                    segmenter.apply(k, k / 10, stream[k])
                    if mode == "observe" or (mode == "coalesced" and (k + 1) % every == 0):
                        segmenter.decide()
            timings.append(1e6 * (time.thread_time() - started) / max(1, frames))
    return timings[0], timings[1], timings[2], frames

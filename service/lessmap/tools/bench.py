"""``lessmap bench fleet``: N simulated robots at R Hz over real Zenoh against ``lessmap serve``.

Processes, all on 127.0.0.1 and each stopped by its PID (SIGTERM, then kill):

- the service: ``python -m lessmap serve -m router -l tcp/127.0.0.1:PORT`` with metrics;
- 1-2 load generators, ``python -m lessmap.tools.bench SPEC.json``: one client Zenoh session
  each and one ``RobotPublisher`` per robot, paced in real time (robot i of N publishes frame
  k at ``t0 + k/R + i/(N R)``: phases spread evenly over the period);
- this process: the fleet app (a ``FleetClient`` that timestamps every transition), the RSS
  and CPU sampler, the offline baseline and the report.

Streams come from the seeded building simulator (``lessmap_client.adapters.sim``): robots walk
through offices, so CovGraphs grow and transitions happen. The features-per-frame target F is
met by landmark density: the wall landmark spacing is scaled until a short calibration run
averages F features per frame (frames keep their natural spread around F; none is padded or
cut). Generator g simulates its robots in its own building (seed ``1000 * seed + g``).

Lost frames are counted by seq on the service side: after every robot sent its
``SessionEnd`` and every session is closed, ``FleetClient.states`` gives each session's
``frames_applied`` and ``frames_missing``; lost = offered - applied.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from lessmap_client import FleetClient

_CALIBRATION_FRAMES = 200
_DEFAULT_SPACING_M = 0.6  # the sim's landmark spacing is drawn in (a, 2a); default a = 0.6
_SAMPLE_PERIOD_S = 0.5  # RSS and CPU samples
_BASELINE_ROBOTS = 4
_KNEE_ROBOTS = (25, 50, 100, 150, 200, 300, 400, 600, 800, 1000)
_QUEUE_P99_TARGET_S = 0.25
_RSS_FLAT_FRACTION = 0.05  # growth over the load's second half above this share: not flat
_CLK_TCK = os.sysconf("SC_CLK_TCK")


# -- what to run ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class LoadSpec:
    """One load run: N robots x R Hz x F features per frame for a bounded duration."""

    robots: int = 200
    rate_hz: float = 10.0
    features: int = 20
    duration_s: float = 60.0
    seed: int = 0
    generators: int = 2
    rooms: int = 12
    fleet: str = "bench"
    workers: int | None = None  # service shards (None: the service default)
    max_batch_frames: int | None = None  # None: the service default (coalescing on)
    baseline_robots: int = _BASELINE_ROBOTS
    speed_mps: float = 0.5  # the simulator's walking speed (its default)
    dwell_s: tuple[float, float] = (0.0, 3.0)  # pause at each waypoint (the sim's default)

    @property
    def frames_per_robot(self) -> int:
        """Frames each robot publishes."""
        return max(1, round(self.duration_s * self.rate_hz))

    @property
    def warmup_s(self) -> float:
        """Warm-up: the first half of the load, while CovGraphs, histories and caches fill.

        RSS must be flat (grow by at most 5 %) over the second half.
        """
        return self.duration_s / 2

    def sim_options(self) -> dict[str, Any]:
        """Motion options handed to the simulator."""
        return {"speed_mps": self.speed_mps, "dwell_s": tuple(self.dwell_s)}

    def robots_of(self, generator: int) -> list[int]:
        """Global robot indices a generator publishes (round robin)."""
        return list(range(generator, self.robots, self.generators))


def robot_name(index: int) -> str:
    """Name of robot ``index`` on the wire."""
    return f"robot{index:04d}"


def stream_seed(seed: int, generator: int) -> int:
    """Simulator seed of a generator's building and robots."""
    return 1000 * seed + generator


def calibrate_spacing(
    features: int, *, seed: int = 0, rooms: int = 12, rate_hz: float = 10.0
) -> float:
    """Return the landmark spacing a (metres, drawn in (a, 2a)) giving ``features`` per frame.

    The mean count of visible landmarks is about inversely proportional to their spacing;
    three fixed-point steps on a short two-robot run land within a few percent.
    """
    spacing = _DEFAULT_SPACING_M
    for _ in range(3):
        mean = _sim_mean_features(spacing, seed=seed, rooms=rooms, rate_hz=rate_hz)
        spacing = min(10.0, max(0.05, spacing * mean / features))
    return round(spacing, 4)


def _sim_mean_features(spacing: float, *, seed: int, rooms: int, rate_hz: float) -> float:
    from lessmap_client.adapters.sim import simulate

    run = simulate(
        seed=stream_seed(seed, 0),
        rooms=rooms,
        robots=2,
        frames_per_robot=_CALIBRATION_FRAMES,
        rate_hz=rate_hz,
        landmark_spacing_m=(spacing, 2 * spacing),
    )
    return sum(len(f["features"]) for f in run.frames) / max(1, len(run.frames))


def simulated_streams(
    spec: LoadSpec, generator: int, spacing: float, robots: int | None = None
) -> list[list[list[int]]]:
    """Return the feature lists, per local robot and frame, of a generator's robots."""
    from lessmap_client.adapters.sim import simulate

    count = len(spec.robots_of(generator)) if robots is None else robots
    run = simulate(
        seed=stream_seed(spec.seed, generator),
        rooms=spec.rooms,
        robots=count,
        frames_per_robot=spec.frames_per_robot,
        rate_hz=spec.rate_hz,
        landmark_spacing_m=(spacing, 2 * spacing),
        **spec.sim_options(),
    )
    streams: list[list[list[int]]] = [[] for _ in range(count)]
    for frame in run.frames:  # sorted by stamp, so each robot's frames stay in seq order
        streams[int(frame["robot"].removeprefix("robot"))].append(list(frame["features"]))
    return streams


# -- the load generator process --------------------------------------------------------------


def generator_main(spec_path: str) -> int:
    """Run one load generator (``python -m lessmap.tools.bench SPEC.json``).

    Protocol on stdio: writes ``ready`` once its publishers are declared and the service is
    alive, reads the start time t0 (Unix seconds) as one line, publishes, ends every session,
    writes the results JSON to ``spec["out"]`` and exits.
    """
    from lessmap_client import RobotPublisher, open_session

    job = json.loads(Path(spec_path).read_text(encoding="utf-8"))
    spec = LoadSpec(**{**job["spec"], "dwell_s": tuple(job["spec"]["dwell_s"])})
    generator: int = job["generator"]
    indices = spec.robots_of(generator)
    started = time.process_time()
    streams = simulated_streams(spec, generator, job["spacing"])
    sim_s = time.process_time() - started
    period = 1.0 / spec.rate_hz
    published: list[list[float]] = [[] for _ in indices]
    lateness_max = 0.0
    late_frames = 0
    session = open_session([job["endpoint"]], timeout_s=30.0)
    try:
        publishers = [
            RobotPublisher(spec.fleet, robot_name(i), session=session, cache=100) for i in indices
        ]
        if not publishers[0].wait_for_service(30.0):
            sys.stderr.write("no lessmap service alive\n")
            return 1
        sys.stdout.write("ready\n")
        sys.stdout.flush()
        ready, _, _ = select.select([sys.stdin], [], [], 300.0)
        if not ready:
            return 1
        t0 = float(sys.stdin.readline())
        cpu_start = time.process_time()
        offsets = [i * period / spec.robots for i in indices]
        for k in range(spec.frames_per_robot):
            base = t0 + k * period
            for local, publisher in enumerate(publishers):
                target = base + offsets[local]
                delay = target - time.time()
                if delay > 0:
                    time.sleep(delay)
                elif -delay > period:
                    late_frames += 1
                lateness_max = max(lateness_max, -delay)
                published[local].append(time.time())
                publisher.publish(streams[local][k], stamp_s=target)
        for publisher in publishers:
            publisher.close()  # SessionEnd with last_seq: the service counts a lost tail
    finally:
        session.close()
    frames = [f for stream in streams for f in stream]
    result = {
        "robots": [robot_name(i) for i in indices],
        "published_s": published,
        "offered": sum(len(p) for p in published),
        "features_mean": sum(len(f) for f in frames) / max(1, len(frames)),
        "lateness_max_s": lateness_max,
        "late_frames": late_frames,
        "cpu_s": time.process_time() - cpu_start,  # publishing and ending the sessions
        "sim_cpu_s": sim_s,
    }
    Path(job["out"]).write_text(json.dumps(result), encoding="utf-8")
    return 0


# -- measuring the service --------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Histogram:
    """A Prometheus histogram: bucket upper bounds and cumulative counts."""

    bounds: tuple[float, ...]
    cumulative: tuple[float, ...]
    count: float
    total: float

    def quantile(self, q: float) -> float:
        """Upper bound of the bucket holding the q-quantile (inf past the last bound)."""
        if self.count <= 0:
            return math.nan
        for bound, seen in zip(self.bounds, self.cumulative, strict=True):
            if seen >= q * self.count:
                return bound
        return math.inf

    @property
    def mean(self) -> float:
        """Mean of the observations."""
        return self.total / self.count if self.count else math.nan


_SAMPLE = re.compile(r"^([a-zA-Z_:][\w:]*)(\{[^}]*\})?\s+(\S+)$")


def parse_metrics(text: str) -> dict[str, float]:
    """Return every sample of a Prometheus text exposition as ``name{labels}`` -> value."""
    samples: dict[str, float] = {}
    for line in text.splitlines():
        match = _SAMPLE.match(line)
        if match and not line.startswith("#"):
            samples[match[1] + (match[2] or "")] = float(match[3])
    return samples


def histogram(samples: dict[str, float], name: str) -> Histogram:
    """Extract one histogram from ``parse_metrics`` output."""
    buckets: list[tuple[float, float]] = []
    for key, value in samples.items():
        if key.startswith(f"{name}_bucket{{"):
            le = re.search(r'le="([^"]+)"', key)
            if le:
                buckets.append((float(le[1]), value))
    buckets.sort()
    return Histogram(
        tuple(b for b, _ in buckets),
        tuple(c for _, c in buckets),
        samples.get(f"{name}_count", 0.0),
        samples.get(f"{name}_sum", 0.0),
    )


def free_port() -> int:
    """Return a TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


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


def load_average() -> tuple[float, float, float]:
    """The 1, 5 and 15 minute load averages."""
    one, five, fifteen = Path("/proc/loadavg").read_text().split()[:3]
    return float(one), float(five), float(fifteen)


class ServiceProcess:
    """``python -m lessmap serve`` as a router on a fresh loopback port, with metrics."""

    def __init__(self, spec: LoadSpec, log_path: Path) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.metrics_port = free_port()
        self.instance = f"bench-{os.getpid()}"
        args = [
            sys.executable,
            "-m",
            "lessmap",
            "serve",
            "-m",
            "router",
            "-l",
            self.endpoint,
            "--cfg",
            "scouting/multicast/enabled:false",
            "--metrics-port",
            str(self.metrics_port),
            "--instance",
            self.instance,
        ]
        if spec.workers is not None:
            args += ["--workers", str(spec.workers)]
        if spec.max_batch_frames is not None:
            args += ["--max-batch-frames", str(spec.max_batch_frames)]
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

    def log_tail(self, lines: int = 20) -> str:
        """The last lines the service logged."""
        text = self.log_path.read_text(encoding="utf-8", errors="replace")
        return "\n".join(text.splitlines()[-lines:])


@dataclass(slots=True)
class Sampler:
    """Samples the service's RSS and CPU every half second on a thread."""

    pid: int
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
        while not self._stop.wait(_SAMPLE_PERIOD_S):
            with contextlib.suppress(OSError, ValueError):
                self.samples.append(
                    (
                        time.time() - self.t0,
                        proc_status_kib(self.pid, "VmRSS"),
                        proc_cpu_s(self.pid),
                    )
                )

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


# -- the report --------------------------------------------------------------------------------


@dataclass(slots=True, kw_only=True)
class LoadReport:
    """Everything one load run measured (``as_dict`` for JSON)."""

    spec: LoadSpec
    landmark_spacing_m: float
    features_mean: float
    load_before: tuple[float, float, float]
    load_after: tuple[float, float, float]
    cpus: int
    offered: int
    applied: int
    missing: int
    duplicate: int
    rejected: int
    sessions_reported: int
    drained: bool
    drain_s: float
    lateness_max_s: float
    late_frames: int
    generator_cpu_s: float
    decisions: float
    coalesced_batches: float
    transitions_service: int
    transitions_received: int
    robots_with_transitions: list[str]
    queue_latency: Histogram
    frame_latency: Histogram  # empty (count 0) when the service does not export it
    decision_seconds: Histogram
    e2e_s: list[float]  # publish -> transition received, sorted
    service_cpu_s: float
    service_cpu_load_s: float  # CPU while the generators published
    service_threads_cpu_s: dict[str, float]  # since start, by thread name
    rss_samples: list[tuple[float, int, float]]
    rss_hwm_kib: int
    baseline_observe_us: float
    baseline_apply_us: float
    baseline_coalesced_us: float
    baseline_frames: int
    baseline_robots: int = 0
    applied_by_robot: dict[str, int] = field(default_factory=dict)
    offered_by_robot: dict[str, int] = field(default_factory=dict)
    transitions_by_robot: dict[str, list[int]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def lost(self) -> int:
        """Frames offered but never applied."""
        return self.offered - self.applied

    @property
    def frames_per_decision(self) -> float:
        """Mean frames a spectral decision covered (coalescing)."""
        return self.applied / self.decisions if self.decisions else math.nan

    @property
    def service_us_per_frame(self) -> float:
        """Service CPU per applied frame, microseconds."""
        return 1e6 * self.service_cpu_s / self.applied if self.applied else math.nan

    def rss_growth(self) -> tuple[float, float, float]:
        """(RSS at the end of warm-up, at the end of the load, relative growth), MiB."""
        load_end = self.spec.duration_s
        window = [s for s in self.rss_samples if self.spec.warmup_s <= s[0] <= load_end]
        if len(window) < 2:
            return math.nan, math.nan, math.nan
        first = sum(s[1] for s in window[:3]) / len(window[:3]) / 1024
        last = sum(s[1] for s in window[-3:]) / len(window[-3:]) / 1024
        return first, last, (last - first) / first

    @property
    def rss_flat(self) -> bool:
        """RSS grew by at most 5 % over the second half of the load."""
        growth = self.rss_growth()[2]
        return not math.isnan(growth) and growth <= _RSS_FLAT_FRACTION

    def e2e(self, q: float) -> float:
        """Quantile of publish -> transition received, seconds."""
        if not self.e2e_s:
            return math.nan
        return self.e2e_s[min(len(self.e2e_s) - 1, int(q * len(self.e2e_s)))]

    @property
    def service_latency(self) -> tuple[str, Histogram]:
        """The service-side latency the bar is judged on, and its name.

        ``lessmap_frame_latency_seconds`` (receipt to the end of the covering decision) when
        the service exports it; otherwise ``lessmap_queue_latency_seconds`` (receipt to the
        start of the worker round), which leaves the round itself out.
        """
        if self.frame_latency.count > 0:
            return "receipt->decision", self.frame_latency
        return "queue wait", self.queue_latency

    def passes(self) -> bool:
        """The issue's bar: 0 lost, p99 service latency <= 250 ms, RSS flat."""
        return (
            self.drained
            and self.lost == 0
            and self.service_latency[1].quantile(0.99) <= _QUEUE_P99_TARGET_S
            and self.rss_flat
        )

    def as_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (seconds, KiB)."""
        rss = self.rss_growth()
        return {
            "spec": asdict(self.spec),
            "landmark_spacing_m": self.landmark_spacing_m,
            "features_mean": self.features_mean,
            "load_average": {"before": self.load_before, "after": self.load_after},
            "cpus": self.cpus,
            "frames": {
                "offered": self.offered,
                "applied": self.applied,
                "lost": self.lost,
                "missing": self.missing,
                "duplicate": self.duplicate,
                "rejected": self.rejected,
            },
            "sessions_reported": self.sessions_reported,
            "drained": self.drained,
            "drain_s": self.drain_s,
            "generator": {
                "lateness_max_s": self.lateness_max_s,
                "late_frames": self.late_frames,
                "cpu_s": self.generator_cpu_s,
            },
            "decisions": self.decisions,
            "coalesced_batches": self.coalesced_batches,
            "frames_per_decision": self.frames_per_decision,
            "transitions": {
                "service": self.transitions_service,
                "received": self.transitions_received,
                "robots": len(self.robots_with_transitions),
            },
            "queue_latency_s": _histogram_dict(self.queue_latency),
            "frame_latency_s": _histogram_dict(self.frame_latency),
            "decision_s": _histogram_dict(self.decision_seconds),
            "publish_to_transition_s": {
                "p50": self.e2e(0.5),
                "p99": self.e2e(0.99),
                "max": self.e2e_s[-1] if self.e2e_s else math.nan,
                "n": len(self.e2e_s),
            },
            "service": {
                "cpu_s": self.service_cpu_s,
                "cpu_during_load_s": self.service_cpu_load_s,
                "cpu_by_thread_s": self.service_threads_cpu_s,
                "us_per_frame": self.service_us_per_frame,
                "rss_hwm_kib": self.rss_hwm_kib,
                "rss_half_mib": rss[0],
                "rss_end_mib": rss[1],
                "rss_growth": rss[2],
                "rss_flat": self.rss_flat,
                "rss_samples": [[round(t, 2), kib] for t, kib, _ in self.rss_samples],
            },
            "baseline": {
                "frames": self.baseline_frames,
                "observe_us": self.baseline_observe_us,
                "apply_us": self.baseline_apply_us,
                "coalesced_us": self.baseline_coalesced_us,
            },
            "passes": self.passes(),
            "notes": self.notes,
        }


def _histogram_dict(h: Histogram) -> dict[str, float]:
    return {"p50_le": h.quantile(0.5), "p99_le": h.quantile(0.99), "mean": h.mean, "count": h.count}


def _ms(seconds: float, *, bound: bool = False) -> str:
    if math.isnan(seconds):
        return "-"
    if math.isinf(seconds):
        return "> 5 s" if bound else "inf"
    return f"{'≤ ' if bound else ''}{1000 * seconds:.1f} ms"


def format_report(r: LoadReport) -> str:
    """Human-readable report: figures, targets, and the offline baseline side by side."""
    s = r.spec
    rss = r.rss_growth()
    basis, judged = r.service_latency
    p99 = judged.quantile(0.99)
    nominal = s.robots * s.rate_hz
    cpu_share = r.service_cpu_load_s / s.duration_s
    ok = {True: "ok", False: "MISSED"}
    lines = [
        f"lessmap fleet load: {s.robots} robots × {s.rate_hz:g} Hz × {s.features} features "
        f"(mean {r.features_mean:.1f}/frame, landmark spacing {r.landmark_spacing_m:g} m) "
        f"for {s.duration_s:g} s; {s.generators} generator process(es); seed {s.seed}",
        f"machine: {r.cpus} CPUs, load average {r.load_before[0]:.2f} before, "
        f"{r.load_after[0]:.2f} after (1 min)",
        "",
        f"frames      offered {r.offered}  applied {r.applied}  LOST {r.lost}  missing "
        f"{r.missing}  duplicate {r.duplicate}  rejected {r.rejected}  "
        f"(sessions reported {r.sessions_reported}/{s.robots}, drained {r.drained})",
        f"offered     {r.offered / s.duration_s:.0f} frames/s (nominal {nominal:.0f}); generator "
        f"lateness max {_ms(r.lateness_max_s)}, {r.late_frames} frame(s) over one period late; "
        f"generator CPU {r.generator_cpu_s:.1f} s",
        f"decisions   {r.decisions:.0f} ({r.frames_per_decision:.2f} frames/decision, "
        f"{r.coalesced_batches:.0f} coalesced); transitions {r.transitions_service} "
        f"(received {r.transitions_received}, {len(r.robots_with_transitions)} robots)",
        f"drain       {r.drain_s:.1f} s from the last publish until every session was closed",
        "",
        "latency (what each measures)                                p50        p99        max",
        f"  queue wait: receipt in the service -> its worker round    "
        f"{_ms(r.queue_latency.quantile(0.5), bound=True):>9}  "
        f"{_ms(r.queue_latency.quantile(0.99), bound=True):>9}  "
        f"(histogram, n={r.queue_latency.count:.0f}, mean {_ms(r.queue_latency.mean)})",
        "  receipt -> end of the decision covering it, all frames  "
        + (
            f"{_ms(r.frame_latency.quantile(0.5), bound=True):>9}  "
            f"{_ms(r.frame_latency.quantile(0.99), bound=True):>9}  "
            f"(histogram, n={r.frame_latency.count:.0f}, mean {_ms(r.frame_latency.mean)})"
            if r.frame_latency.count
            else "(lessmap_frame_latency_seconds not exported by this service)"
        ),
        f"  one spectral decision (apply excluded)                   "
        f"{_ms(r.decision_seconds.quantile(0.5), bound=True):>9}  "
        f"{_ms(r.decision_seconds.quantile(0.99), bound=True):>9}  "
        f"(histogram, n={r.decision_seconds.count:.0f}, mean {_ms(r.decision_seconds.mean)})",
        f"  publish -> Transition received, transition frames only  {_ms(r.e2e(0.5)):>9}  "
        f"{_ms(r.e2e(0.99)):>9}  {_ms(r.e2e_s[-1] if r.e2e_s else math.nan):>9}  "
        f"(n={len(r.e2e_s)})",
        "",
        f"service     CPU {r.service_cpu_s:.1f} s ({100 * cpu_share:.0f} % of one core during "
        f"the load), {r.service_us_per_frame:.0f} µs per applied frame",
        f"            CPU by thread since start (s): {_threads_line(r.service_threads_cpu_s)}",
        f"            RSS peak (VmHWM) {r.rss_hwm_kib / 1024:.0f} MiB; RSS {rss[0]:.0f} MiB at "
        f"half-time ({s.warmup_s:g} s) -> {rss[1]:.0f} MiB at the end of the load "
        f"({100 * rss[2]:+.1f} %): {'flat' if r.rss_flat else 'GROWING'}",
        f"            RSS samples (s: MiB) {_rss_line(r.rss_samples)}",
        "",
        f"baseline    same streams, core in this process, one thread ({r.baseline_frames} frames "
        f"of {r.baseline_robots} robots):",
        f"  core observe (apply + decide every frame)   {r.baseline_observe_us:8.0f} µs/frame",
        f"  core apply only (CovGraph counting)         {r.baseline_apply_us:8.0f} µs/frame",
        f"  core at the service's coalescing ({r.frames_per_decision:.2f} f/d)  "
        f"{r.baseline_coalesced_us:8.0f} µs/frame",
        f"  service CPU per applied frame               {r.service_us_per_frame:8.0f} µs/frame  "
        f"= {_ratio(r.service_us_per_frame, r.baseline_coalesced_us)} the core at the same "
        f"coalescing, {_ratio(r.service_us_per_frame, r.baseline_observe_us)} core observe",
        "",
        f"targets     lost 0: {ok[r.lost == 0 and r.drained]};  p99 {basis} ≤ 250 ms: "
        f"{ok[p99 <= _QUEUE_P99_TARGET_S]};  p99 publish->transition ≤ 250 ms: "
        f"{ok[r.e2e(0.99) <= _QUEUE_P99_TARGET_S] if r.e2e_s else 'no transitions'};  "
        f"RSS flat: {ok[r.rss_flat]}",
    ]
    lines += [f"note        {note}" for note in r.notes]
    return "\n".join(lines) + "\n"


def _threads_line(by_name: dict[str, float], top: int = 8) -> str:
    return ", ".join(f"{name} {cpu:.1f}" for name, cpu in list(by_name.items())[:top]) or "-"


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}×" if b and not math.isnan(a) and not math.isnan(b) else "-"


def _rss_line(samples: list[tuple[float, int, float]], points: int = 12) -> str:
    if not samples:
        return "-"
    step = max(1, len(samples) // points)
    return ", ".join(f"{t:.0f}: {kib / 1024:.0f}" for t, kib, _ in samples[::step])


# -- offline baseline ---------------------------------------------------------------------------


def offline_baseline(
    streams: list[list[list[int]]], frames_per_decision: float
) -> tuple[float, float, float, int]:
    """Time the core alone on streams: (observe, apply, coalesced) µs per frame, frames.

    One thread (BLAS limited to one, as the service runs it); robots interleaved frame by
    frame as the service sees them.
    """
    from threadpoolctl import threadpool_limits

    from lessmap.core import Partitioner, PartitionParams

    params = PartitionParams.from_profile("laser")
    frames = sum(len(s) for s in streams)
    every = max(1, round(frames_per_decision)) if not math.isnan(frames_per_decision) else 1
    timings: list[float] = []
    with threadpool_limits(limits=1):
        for mode in ("observe", "apply", "coalesced"):
            partitioners = [Partitioner(params) for _ in streams]
            started = time.perf_counter()
            for k in range(max((len(s) for s in streams), default=0)):
                for stream, partitioner in zip(streams, partitioners, strict=True):
                    if k >= len(stream):
                        continue
                    if mode == "observe":
                        partitioner.observe(k, k / 10, stream[k])
                        continue
                    partitioner.apply(k, k / 10, stream[k])
                    if mode == "coalesced" and (k + 1) % every == 0:
                        partitioner.decide()
            timings.append(1e6 * (time.perf_counter() - started) / max(1, frames))
    return timings[0], timings[1], timings[2], frames


# -- one run -------------------------------------------------------------------------------------


def run_load(
    spec: LoadSpec,
    *,
    profile: Path | None = None,
    profile_duration_s: float = 20.0,
    log: IO[str] | None = None,
) -> LoadReport:
    """Start the service and the generators, run the load, stop everything, measure.

    Args:
        spec: what to run.
        profile: if set, ``py-spy record`` the service after warm-up into this file (raw
            collapsed stacks; ``.svg``: a flame graph) and write a summary next to it.
        profile_duration_s: seconds of profile.
        log: progress lines go here (None: quiet).
    """
    from lessmap_client import FleetClient, open_session

    def say(text: str) -> None:
        if log is not None:
            log.write(f"[bench] {text}\n")
            log.flush()

    if spec.robots < 1 or spec.generators < 1 or spec.rate_hz <= 0 or spec.duration_s <= 0:
        msg = f"need robots, generators, rate and duration > 0, got {spec}"
        raise ValueError(msg)
    spec = replace(spec, generators=min(spec.generators, spec.robots))
    spacing = calibrate_spacing(
        spec.features, seed=spec.seed, rooms=spec.rooms, rate_hz=spec.rate_hz
    )
    say(f"landmark spacing {spacing} m for {spec.features} features/frame")
    load_before = load_average()
    with tempfile.TemporaryDirectory(prefix="lessmap-bench-") as tmp:
        work = Path(tmp)
        service = ServiceProcess(spec, work / "serve.log")
        generators: list[subprocess.Popen[bytes]] = []
        pyspy: subprocess.Popen[bytes] | None = None
        try:
            service.wait_ready()
            say(f"service pid {service.pid} on {service.endpoint}")
            session = open_session([service.endpoint], timeout_s=30.0)
            try:
                with FleetClient(spec.fleet, session=session, history=0) as client:
                    transitions = TransitionLog(client)
                    transitions.start()
                    for g in range(spec.generators):
                        generators.append(
                            _start_generator(spec, g, spacing, service.endpoint, work)
                        )
                    for g, process in enumerate(generators):
                        _wait_line(process, "ready", 600.0, f"generator {g}")
                    say(
                        f"{spec.generators} generator(s) ready; publishing for "
                        f"{spec.duration_s:g} s"
                    )
                    t0 = time.time() + 1.0
                    for process in generators:
                        assert process.stdin is not None
                        process.stdin.write(f"{t0!r}\n".encode())
                        process.stdin.flush()
                    sampler = Sampler(service.pid)
                    sampler.start(t0)
                    time.sleep(max(0.0, t0 - time.time()))
                    cpu_start = proc_cpu_s(service.pid)
                    if profile is not None:
                        time.sleep(min(10.0, spec.duration_s / 4))
                        pyspy = _start_pyspy(service.pid, profile, profile_duration_s)
                    results = _wait_generators(generators, spec, work)
                    load_end = time.time()
                    cpu_load = proc_cpu_s(service.pid) - cpu_start
                    say("load done; waiting for every session to close")
                    states, drained = _wait_closed(client, spec, 30.0 + 2 * spec.duration_s)
                    drain_s = time.time() - load_end
                    service_cpu = proc_cpu_s(service.pid) - cpu_start
                    metrics = parse_metrics(service.metrics_text())
                    hwm = proc_status_kib(service.pid, "VmHWM")
                    threads_cpu = thread_cpu_s(service.pid)
                    transitions.wait_for(sum(s.transitions for s in states), 10.0)
                    transitions.stop()
                    sampler.stop()
            finally:
                session.close()
            if pyspy is not None:
                _finish_pyspy(pyspy, profile, profile_duration_s, say)
                pyspy = None
        finally:
            if pyspy is not None:
                stop_process(pyspy)
            for process in generators:
                stop_process(process)
            code = stop_process(service.process, 30.0)
            if code not in (0, None):
                say(f"service exited with {code}: {service.log_tail()}")
    report = _build_report(
        spec,
        spacing,
        load_before,
        results,
        states,
        drained,
        drain_s,
        metrics,
        transitions.received,
        service_cpu,
        cpu_load,
        sampler.samples,
        hwm,
        threads_cpu,
    )
    baseline_streams = simulated_streams(
        spec, 0, spacing, robots=min(spec.baseline_robots, len(spec.robots_of(0)))
    )
    observe, apply, coalesced, frames = offline_baseline(
        baseline_streams, report.frames_per_decision
    )
    report.baseline_observe_us = observe
    report.baseline_apply_us = apply
    report.baseline_coalesced_us = coalesced
    report.baseline_frames = frames
    report.baseline_robots = len(baseline_streams)
    return report


def _start_generator(
    spec: LoadSpec, generator: int, spacing: float, endpoint: str, work: Path
) -> subprocess.Popen[bytes]:
    job = {
        "spec": asdict(spec),
        "generator": generator,
        "spacing": spacing,
        "endpoint": endpoint,
        "out": str(work / f"generator-{generator}.json"),
    }
    path = work / f"generator-{generator}.spec.json"
    path.write_text(json.dumps(job), encoding="utf-8")
    log = (work / f"generator-{generator}.log").open("wb")
    with log:
        return subprocess.Popen(
            [sys.executable, "-m", "lessmap.tools.bench", str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log,
        )


def _wait_line(
    process: subprocess.Popen[bytes], expected: str, timeout_s: float, what: str
) -> None:
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    line = process.stdout.readline().decode().strip() if ready else ""
    if line != expected:
        msg = f"{what} did not start (exit {process.poll()}, said {line!r})"
        raise RuntimeError(msg)


def _wait_generators(
    generators: list[subprocess.Popen[bytes]], spec: LoadSpec, work: Path
) -> list[dict[str, Any]]:
    deadline = time.monotonic() + 2 * spec.duration_s + 120.0
    results = []
    for g, process in enumerate(generators):
        code: int | None
        try:
            code = process.wait(max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            code = stop_process(process)
        if code != 0:
            log = (work / f"generator-{g}.log").read_text(errors="replace")[-2000:]
            msg = f"generator {g} exited with {code}: {log}"
            raise RuntimeError(msg)
        results.append(json.loads((work / f"generator-{g}.json").read_text(encoding="utf-8")))
    return results


def _wait_closed(client: FleetClient, spec: LoadSpec, timeout_s: float) -> tuple[list[Any], bool]:
    """Poll the states until every robot's session is closed; (states, all closed)."""
    deadline = time.monotonic() + timeout_s
    states: list[Any] = []
    while True:
        states = client.states(spec.fleet, timeout_s=10.0)
        if len(states) >= spec.robots and not any(state.open for state in states):
            return states, True
        if time.monotonic() > deadline:
            return states, False
        time.sleep(0.5)


def _build_report(
    spec: LoadSpec,
    spacing: float,
    load_before: tuple[float, float, float],
    results: list[dict[str, Any]],
    states: list[Any],
    drained: bool,
    drain_s: float,
    metrics: dict[str, float],
    received: list[tuple[str, int, int, float]],
    service_cpu: float,
    cpu_load: float,
    samples: list[tuple[float, int, float]],
    hwm: int,
    threads_cpu: dict[str, float],
) -> LoadReport:
    published: dict[str, list[float]] = {}
    for result in results:
        published.update(zip(result["robots"], result["published_s"], strict=True))
    e2e = sorted(
        at - published[robot][seq]
        for robot, seq, _batch, at in received
        if robot in published and seq < len(published[robot])
    )
    by_robot: dict[str, list[int]] = {}
    for robot, seq, _batch, _at in received:
        by_robot.setdefault(robot, []).append(seq)
    frames = sum(r["offered"] for r in results)
    report = LoadReport(
        spec=spec,
        landmark_spacing_m=spacing,
        features_mean=sum(r["features_mean"] * r["offered"] for r in results) / max(1, frames),
        load_before=load_before,
        load_after=load_average(),
        cpus=os.cpu_count() or 1,
        offered=frames,
        applied=sum(s.frames_applied for s in states),
        missing=sum(s.frames_missing for s in states),
        duplicate=sum(s.frames_duplicate for s in states),
        rejected=sum(s.frames_rejected for s in states),
        sessions_reported=len(states),
        drained=drained,
        drain_s=drain_s,
        lateness_max_s=max(r["lateness_max_s"] for r in results),
        late_frames=sum(r["late_frames"] for r in results),
        generator_cpu_s=sum(r["cpu_s"] for r in results),
        decisions=metrics.get("lessmap_decisions_total", 0.0),
        coalesced_batches=metrics.get("lessmap_coalesced_batches_total", 0.0),
        transitions_service=sum(s.transitions for s in states),
        transitions_received=len(received),
        robots_with_transitions=sorted(by_robot),
        queue_latency=histogram(metrics, "lessmap_queue_latency_seconds"),
        frame_latency=histogram(metrics, "lessmap_frame_latency_seconds"),
        decision_seconds=histogram(metrics, "lessmap_decision_seconds"),
        e2e_s=e2e,
        service_cpu_s=service_cpu,
        service_cpu_load_s=cpu_load,
        service_threads_cpu_s=threads_cpu,
        rss_samples=samples,
        rss_hwm_kib=hwm,
        baseline_observe_us=math.nan,
        baseline_apply_us=math.nan,
        baseline_coalesced_us=math.nan,
        baseline_frames=0,
        applied_by_robot={s.robot: s.frames_applied for s in states},
        offered_by_robot={robot: len(times) for robot, times in published.items()},
        transitions_by_robot=by_robot,
    )
    counted = metrics.get("lessmap_frames_applied_total", 0.0)
    if counted != report.applied:
        report.notes.append(
            f"lessmap_frames_applied_total {counted:.0f} != states {report.applied}"
        )
    if report.late_frames:
        report.notes.append(
            "the generators fell behind schedule: the offered rate is below "
            "nominal (CPU shared with the service, or Zenoh back-pressure)"
        )
    return report


# -- profile ---------------------------------------------------------------------------------


def _start_pyspy(pid: int, out: Path, duration_s: float) -> subprocess.Popen[bytes]:
    exe = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
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


def summarize_profile(raw: str, top: int = 25) -> str:
    """Summarize py-spy raw (collapsed) stacks: share of samples by thread, self, inclusive.

    Frames are merged by function and file (line numbers dropped), so a function counts
    once however many of its lines were sampled.
    """
    own: dict[str, float] = {}
    inclusive: dict[str, float] = {}
    threads: dict[str, float] = {}
    total = 0.0
    for line in raw.splitlines():
        stack, _, count_text = line.rpartition(" ")
        if not stack or not count_text.isdigit():
            continue
        count = float(count_text)
        thread, *calls = stack.split(";")
        calls = [_LINE_NUMBER.sub(")", frame) for frame in calls] or [thread]
        total += count
        name = _THREAD_ID.sub("", thread)
        threads[name] = threads.get(name, 0.0) + count
        own[calls[-1]] = own.get(calls[-1], 0.0) + count
        for frame in set(calls):
            inclusive[frame] = inclusive.get(frame, 0.0) + count
    if not total:
        return "no samples\n"
    lines = [f"{total:.0f} samples of the service thread holding the GIL", "", "by thread:"]
    lines += [f"  {100 * n / total:5.1f} %  {name}" for name, n in _top(threads, top)]
    lines += ["", "self time (the function itself):"]
    lines += [f"  {100 * n / total:5.1f} %  {name}" for name, n in _top(own, top)]
    lines += ["", "inclusive time (the function and what it calls):"]
    lines += [f"  {100 * n / total:5.1f} %  {name}" for name, n in _top(inclusive, top)]
    return "\n".join(lines) + "\n"


_LINE_NUMBER = re.compile(r":\d+\)$")
_THREAD_ID = re.compile(r"^thread \(\d+\): ")


def _top(counts: dict[str, float], top: int) -> list[tuple[str, float]]:
    return sorted(counts.items(), key=lambda item: -item[1])[:top]


# -- the knee --------------------------------------------------------------------------------


def find_knee(
    base: LoadSpec, robots: Sequence[int], log: IO[str] | None = None
) -> tuple[int | None, list[LoadReport]]:
    """Run increasing fleet sizes until one misses the bar; return the largest that met it."""
    reports: list[LoadReport] = []
    knee: int | None = None
    for count in robots:
        report = run_load(replace(base, robots=count), log=log)
        reports.append(report)
        if log is not None:
            log.write(knee_row(report) + "\n")
            log.flush()
        if not report.passes():
            break
        knee = count
    return knee, reports


KNEE_HEADER = (
    "robots  offered/s  lost  svc p99     e2e p99   frames/dec  CPU %  RSS MiB (growth)  "
    "drain s  load  pass"
)


def knee_row(r: LoadReport) -> str:
    """One line of the knee table."""
    rss = r.rss_growth()
    return (
        f"{r.spec.robots:6d}  {r.offered / r.spec.duration_s:9.0f}  {r.lost:4d}  "
        f"{_ms(r.service_latency[1].quantile(0.99), bound=True):>9}  {_ms(r.e2e(0.99)):>8}  "
        f"{r.frames_per_decision:10.2f}  {100 * r.service_cpu_load_s / r.spec.duration_s:5.0f}  "
        f"{rss[1]:7.0f} ({100 * rss[2]:+5.1f} %)  {r.drain_s:7.1f}  {r.load_after[0]:4.1f}  "
        f"{'yes' if r.passes() else 'no'}"
    )


# -- command line ------------------------------------------------------------------------------


def add_fleet_options(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``lessmap bench fleet`` (shared with tests/benchmarks/fleet_load.py)."""
    parser.add_argument("--robots", type=int, default=200, help="robots N (default 200)")
    parser.add_argument("--rate", type=float, default=10.0, help="frames/s per robot (10)")
    parser.add_argument("--features", type=int, default=20, help="mean features per frame (20)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of load (60)")
    parser.add_argument("--seed", type=int, default=0, help="simulator seed (0)")
    parser.add_argument(
        "--generators",
        type=int,
        default=2,
        choices=[1, 2, 3, 4],
        help="load generator processes (default 2)",
    )
    parser.add_argument("--rooms", type=int, default=12, help="rooms per building (12)")
    parser.add_argument("--workers", type=int, help="service shards (default: its own, 1)")
    parser.add_argument(
        "--max-batch-frames",
        type=int,
        help="service coalescing bound (default: its own; 1 = decide per frame)",
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument(
        "--find-knee",
        action="store_true",
        help="run increasing N at --rate x --features and report the largest N "
        "with 0 lost, p99 service latency ≤ 250 ms and flat RSS",
    )
    parser.add_argument(
        "--knee-robots",
        type=lambda t: [int(v) for v in t.split(",")],
        default=list(_KNEE_ROBOTS),
        help="fleet sizes for --find-knee, comma separated",
    )
    parser.add_argument(
        "--knee-duration", type=float, default=20.0, help="seconds per --find-knee step (20)"
    )
    parser.add_argument(
        "--profile",
        type=Path,
        metavar="FILE",
        help="py-spy record the service after warm-up: raw collapsed stacks "
        "plus FILE.summary.txt, or a flame graph if FILE ends in .svg",
    )
    parser.add_argument(
        "--profile-duration", type=float, default=20.0, help="seconds of profile (20)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def spec_from_args(args: argparse.Namespace) -> LoadSpec:
    """Build the load spec from parsed options."""
    return LoadSpec(
        robots=args.robots,
        rate_hz=args.rate,
        features=args.features,
        duration_s=args.duration,
        seed=args.seed,
        generators=args.generators,
        rooms=args.rooms,
        workers=args.workers,
        max_batch_frames=args.max_batch_frames,
    )


def _json(data: Any) -> str:
    """Strict JSON: NaN and infinities (no data, or past the last bucket) become null."""

    def finite(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {key: finite(item) for key, item in value.items()}
        if isinstance(value, list | tuple):
            return [finite(item) for item in value]
        return value

    return json.dumps(finite(data), allow_nan=False)


def run_fleet(args: argparse.Namespace) -> int:
    """Run ``lessmap bench fleet``; exit code 0 when the bar is met, 2 when missed."""
    log = None if args.quiet else sys.stderr
    spec = spec_from_args(args)
    if args.find_knee:
        if log is not None:
            log.write(KNEE_HEADER + "\n")
        knee, reports = find_knee(
            replace(spec, duration_s=args.knee_duration), args.knee_robots, log=log
        )
        if args.json:
            sys.stdout.write(
                _json({"knee_robots": knee, "runs": [r.as_dict() for r in reports]}) + "\n"
            )
        else:
            table = "\n".join([KNEE_HEADER, *(knee_row(r) for r in reports)])
            found = f"{knee} robots" if knee is not None else "none of these sizes met the bar"
            sys.stdout.write(
                f"{table}\nknee: {found} at {spec.rate_hz:g} Hz × {spec.features} features\n"
            )
        return 0
    report = run_load(spec, profile=args.profile, profile_duration_s=args.profile_duration, log=log)
    if args.json:
        sys.stdout.write(_json(report.as_dict()) + "\n")
    else:
        sys.stdout.write(format_report(report))
    return 0 if report.passes() else 2


def add_commands(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``bench`` with its ``fleet`` subcommand."""
    bench = commands.add_parser(
        "bench",
        help="benchmarks of the running service",
        description="Benchmarks that run the real service.",
    )
    kinds = bench.add_subparsers(dest="bench", required=True, metavar="BENCH")
    fleet = kinds.add_parser(
        "fleet",
        help="N robots × R Hz × F features over real Zenoh: frames lost, latency, CPU, RSS",
        description="Start `lessmap serve` on a free loopback port and 1-2 load generator "
        "processes that publish simulated robots in real time; print frames offered, applied "
        "and lost, latencies, service CPU and RSS, and an in-process baseline of the core on "
        "the same streams. Exit code 2 when the bar is missed: 0 lost, p99 service latency "
        "≤ 250 ms (receipt to decision if the service exports lessmap_frame_latency_seconds, "
        "else its queue wait), flat RSS.",
    )
    add_fleet_options(fleet)
    fleet.set_defaults(run=run_fleet)


if __name__ == "__main__":
    sys.exit(generator_main(sys.argv[1]))

"""Fleet load benchmark: N simulated robots at R Hz over real Zenoh against ``lessmap serve``.

Processes, all on 127.0.0.1 and each stopped by its PID (SIGTERM, then kill):

- the service: ``python -m lessmap serve -m router -l tcp/127.0.0.1:PORT`` with metrics;
- 1-2 load generators, ``python -m tests.benchmarks.fleet.orchestrate SPEC.json``: one
  client Zenoh session each and one ``RobotPublisher`` per robot, paced in real time (robot i
  of N publishes frame k at ``t0 + k/R + i/(N R)``: phases spread evenly over the period);
- this process: the fleet app (a ``FleetClient`` that timestamps every transition), the RSS
  and CPU sampler, the offline baseline and the report.

Streams come from the seeded building simulator (``lessmap.sim.simulator``): robots walk
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
import json
import math
import os
import select
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from tests.benchmarks.fleet.loadgen import (
    LoadSpec,
    calibrate_spacing,
    generator_main,
    simulated_streams,
)
from tests.benchmarks.fleet.process import (
    Sampler,
    ServiceProcess,
    TransitionLog,
    _finish_pyspy,
    _start_pyspy,
    load_average,
    offline_baseline,
    proc_cpu_s,
    proc_status_kib,
    stop_process,
    thread_cpu_s,
)
from tests.benchmarks.fleet.report import (
    KNEE_HEADER,
    LoadReport,
    _json,
    format_report,
    histogram,
    knee_row,
    parse_metrics,
)

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from lessmap_client import FleetClient

__all__ = [
    "LoadReport",
    "LoadSpec",
    "add_fleet_options",
    "find_knee",
    "format_report",
    "generator_main",
    "run_fleet",
    "run_load",
    "simulated_streams",
]

REPO_ROOT = Path(__file__).resolve().parents[3]
_KNEE_ROBOTS = (25, 50, 100, 150, 200, 300, 400, 600, 800, 1000)


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
        # More instances split the fleet by key hash (--shard I/N); they join the first
        # instance's router, which the generators and the fleet client use.
        others = [
            ServiceProcess(spec, work / f"serve-{i}.log", shard=i, connect=service.endpoint)
            for i in range(1, spec.instances)
        ]
        services = [service, *others]
        generators: list[subprocess.Popen[bytes]] = []
        pyspy: subprocess.Popen[bytes] | None = None
        try:
            for instance in services:
                instance.wait_ready()
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
                    sampler = Sampler(service.pid, [o.pid for o in others])
                    sampler.start(t0)
                    time.sleep(max(0.0, t0 - time.time()))
                    cpu_start = _cpu(services)
                    if profile is not None:
                        time.sleep(min(10.0, spec.duration_s / 4))
                        pyspy = _start_pyspy(service.pid, profile, profile_duration_s)
                    results = _wait_generators(generators, spec, work)
                    load_end = time.time()
                    cpu_load = _cpu(services) - cpu_start
                    say("load done; waiting for every session to close")
                    states, drained = _wait_closed(client, spec, 30.0 + 2 * spec.duration_s)
                    drain_s = time.time() - load_end
                    service_cpu = _cpu(services) - cpu_start
                    metrics = _summed(parse_metrics(i.metrics_text()) for i in services)
                    hwm = sum(proc_status_kib(i.pid, "VmHWM") for i in services)
                    threads_cpu = _summed(thread_cpu_s(i.pid) for i in services)
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
            for instance in reversed(services):  # the router-holding first instance last
                code = stop_process(instance.process, 30.0)
                if code not in (0, None):
                    say(f"service exited with {code}: {instance.log_tail()}")
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


def _cpu(services: list[ServiceProcess]) -> float:
    return sum(proc_cpu_s(instance.pid) for instance in services)


def _summed(parts: Iterable[dict[str, float]]) -> dict[str, float]:
    """Add samples of several instances key by key (counters and histogram buckets add up)."""
    total: dict[str, float] = {}
    for part in parts:
        for key, value in part.items():
            total[key] = total.get(key, 0.0) + value
    return total


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
            [sys.executable, "-m", "tests.benchmarks.fleet.orchestrate", str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log,
            cwd=REPO_ROOT,  # the generator runs as `python -m tests.benchmarks.fleet...`
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


# -- command line ------------------------------------------------------------------------------


def add_fleet_options(parser: argparse.ArgumentParser) -> None:
    """Add the options of the fleet load benchmark (shared with tests/benchmarks/fleet_load.py)."""
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
        "--instances",
        type=int,
        default=1,
        help="service processes splitting the fleet with --shard I/N (default 1)",
    )
    parser.add_argument(
        "--max-batch-frames",
        type=int,
        help="service coalescing bound (default: its own; 1 = decide per frame)",
    )
    parser.add_argument(
        "--batch-linger-ms",
        type=float,
        help="service wait for more frames after a wake-up (default: its own; 0 = off)",
    )
    parser.add_argument(
        "--memory-only",
        action="store_true",
        help="run the service without session checkpoints (default: checkpoints on)",
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
        "--knee-duration",
        type=float,
        default=40.0,
        help="seconds per --find-knee step (40: shorter steps end before the CovGraphs of "
        "200+ robots have grown, and the RSS rule then fails on warm-up)",
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
        instances=args.instances,
        max_batch_frames=args.max_batch_frames,
        batch_linger_ms=args.batch_linger_ms,
        memory_only=args.memory_only,
    )


def run_fleet(args: argparse.Namespace) -> int:
    """Run the fleet load benchmark; exit code 0 when the bar is met, 2 when missed."""
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


if __name__ == "__main__":
    sys.exit(generator_main(sys.argv[1]))

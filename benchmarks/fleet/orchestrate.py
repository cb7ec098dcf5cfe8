"""Fleet load benchmark: N simulated robots at R Hz over real Zenoh against ``lessmap serve``.

Processes, all on 127.0.0.1 and each stopped by its PID (SIGTERM, then kill):

- one instance: ``python -m lessmap serve -m router -l tcp/127.0.0.1:PORT`` with metrics;
  N > 1 instances: ``python -m lessmap router -l tcp/127.0.0.1:PORT`` and N times
  ``python -m lessmap serve -m client -e tcp/127.0.0.1:PORT --instance bench-<pid>-<i>
  --state-dir <run>/state-<i>``, sharing the fleet's partitions (contract section 2a);
  the load starts once each owns its rendezvous share. ``kill_after_s``: one instance is
  killed with SIGKILL mid-run and its robots' take-over is timed (``takeover.py``);
- 1-2 load generators, ``python -m benchmarks.fleet.orchestrate SPEC.json``: one
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

import json
import math
import os
import queue
import select
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from dataclasses import asdict, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from benchmarks.fleet.loadgen import (
    LoadSpec,
    calibrate_spacing,
    generator_main,
    simulated_streams,
)
from benchmarks.fleet.metrics import histogram, parse_metrics
from benchmarks.fleet.process import (
    RouterProcess,
    Sampler,
    ServiceProcess,
    SocketMeter,
    TransitionLog,
    WorkerView,
    _finish_pyspy,
    _start_pyspy,
    load_average,
    offline_baseline,
    proc_cpu_s,
    proc_status_kib,
    stop_all,
    stop_process,
    thread_cpu_s,
)
from benchmarks.fleet.report import InstanceFigures, LoadReport, format_report
from benchmarks.fleet.takeover import TakeoverWatch, _kill_one

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    import zenoh

    from lessmap_client import FleetClient

__all__ = [
    "LoadReport",
    "LoadSpec",
    "format_report",
    "generator_main",
    "run_load",
    "simulated_streams",
]

REPO_ROOT = Path(__file__).resolve().parents[2]


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
    if spec.kill_after_s is not None and not (
        spec.instances * spec.serve_workers >= 2 and 0 < spec.kill_after_s < spec.duration_s - 2.0
    ):
        msg = "a kill needs two instances or workers and 0 < --kill-one-after < --duration - 2"
        raise ValueError(msg)
    spec = replace(spec, generators=min(spec.generators, spec.robots))
    spacing = calibrate_spacing(
        spec.features, seed=spec.seed, rooms=spec.rooms, rate_hz=spec.rate_hz
    )
    say(f"landmark spacing {spacing} m for {spec.features} features/frame")
    load_before = load_average()
    with tempfile.TemporaryDirectory(prefix="lessmap-bench-") as tmp:
        work = Path(tmp)
        # One instance is its own router, as before. Several share the fleet by partition
        # ownership: a plain `lessmap router`, the instances joined to it as clients (each its
        # own name and state directory), and the generators and the fleet app on the router.
        router = RouterProcess(work / "router.log") if spec.instances > 1 else None
        parents: list[ServiceProcess] = []
        services: list[ServiceProcess] | list[WorkerView] = []
        generators: list[subprocess.Popen[bytes]] = []
        pyspy: subprocess.Popen[bytes] | None = None
        watch: TakeoverWatch | None = None
        figures: dict[str, InstanceFigures] = {}
        try:
            if router is not None:
                router.wait_ready()
                say(f"router pid {router.pid} on {router.endpoint}")
            connect = router.endpoint if router is not None else None
            parents = [
                ServiceProcess(spec, work / f"serve-{i}.log", index=i, connect=connect)
                for i in range(spec.instances)
            ]
            # `serve --workers N`: each worker process is measured as an instance of its own.
            services = (
                parents
                if spec.serve_workers == 1
                else [WorkerView(p, w) for p in parents for w in range(spec.serve_workers)]
            )
            service = services[0]
            for instance in services:
                instance.wait_ready()
            owners = _wait_partitions(services, 60.0)
            say(
                "service pid(s) "
                + ", ".join(
                    f"{i.pid} ({i.instance}, {owners[i.instance]} partitions)" for i in services
                )
                + f" on {service.endpoint}"
            )
            session = open_session([service.endpoint], timeout_s=30.0)
            try:
                wire = _CheckpointTap(session) if spec.instances > 1 else None
                with FleetClient(spec.fleet, session=session, history=0) as client:
                    transitions = TransitionLog(client)
                    transitions.start()
                    for g in range(spec.generators):
                        generators.append(
                            _start_generator(spec, g, spacing, service.endpoint, work)
                        )
                    # A generator simulates its robots' whole walk before it says ready.
                    setup_s = 300.0 + spec.duration_s / 2
                    for g, process in enumerate(generators):
                        _wait_line(process, "ready", setup_s, f"generator {g}")
                    say(
                        f"{spec.generators} generator(s) ready; publishing for "
                        f"{spec.duration_s:g} s"
                    )
                    t0 = time.time() + 1.0
                    for process in generators:
                        assert process.stdin is not None
                        process.stdin.write(f"{t0!r}\n".encode())
                        process.stdin.flush()
                    sampler = Sampler(service.pid, [o.pid for o in services[1:]])
                    sampler.start(t0)
                    time.sleep(max(0.0, t0 - time.time()))
                    cpu_start = {i.pid: proc_cpu_s(i.pid) for i in services}
                    # The router's CPU: `lessmap router`'s, or the parent's of `--workers N`
                    # (it hosts the workers' router and supervises them).
                    hub_pid = router.pid if router is not None else None
                    if hub_pid is None and spec.serve_workers > 1:
                        hub_pid = parents[0].pid
                    router_start = proc_cpu_s(hub_pid) if hub_pid is not None else math.nan
                    meter = SocketMeter(router.port) if router is not None else None
                    if meter is not None:
                        meter.start()
                    if profile is not None:
                        time.sleep(min(10.0, spec.duration_s / 4))
                        pyspy = _start_pyspy(service.pid, profile, profile_duration_s)
                    if spec.kill_after_s is not None:
                        watch = _kill_one(spec, services, t0, cpu_start, figures, session, say)
                    results = _wait_generators(generators, spec, work)
                    load_end = time.time()
                    alive = [i for i in services if i.process.poll() is None]
                    cpu_load = {i.pid: proc_cpu_s(i.pid) - cpu_start[i.pid] for i in alive}
                    cpu_load_total = sum(cpu_load.values())
                    cpu_load_total += sum(f.cpu_load_s for f in figures.values())  # killed
                    router_cpu = (
                        proc_cpu_s(hub_pid) - router_start if hub_pid is not None else math.nan
                    )
                    router_bytes = meter.stop() if meter is not None else (0, 0)
                    say("load done; waiting for every session to close")
                    states, drained = _wait_closed(client, spec, 30.0 + 2 * spec.duration_s)
                    drain_s = time.time() - load_end
                    service_cpu = sum(proc_cpu_s(i.pid) - cpu_start[i.pid] for i in alive)
                    service_cpu += sum(f.cpu_load_s for f in figures.values())  # killed
                    per_instance = {i.instance: parse_metrics(i.metrics_text()) for i in alive}
                    metrics = _summed(per_instance.values())
                    hwm = sum(proc_status_kib(i.pid, "VmHWM") for i in alive)
                    threads_cpu = _summed(thread_cpu_s(i.pid) for i in alive)
                    transitions.wait_for(sum(s.transitions for s in states), 10.0)
                    transitions.stop()
                    sampler.stop()
                    takeover = watch.finish() if watch is not None else None
                    for i in alive:
                        figures[i.instance] = InstanceFigures.from_metrics(
                            per_instance[i.instance],
                            name=i.instance,
                            pid=i.pid,
                            robots=0,
                            partitions_at_start=owners[i.instance],
                            frames_offered=0,
                            cpu_load_s=cpu_load[i.pid],
                        )
                    wire_puts, wire_bytes, wire_zlib = (
                        wire.close() if wire is not None else (0, 0, math.nan)
                    )
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
            codes = stop_all([i.process for i in parents])
            for instance, code in zip(parents, codes, strict=True):
                if code not in (0, None, -9):
                    say(f"service {instance.instance} exited with {code}: {instance.log_tail()}")
            if router is not None:
                stop_process(router.process)
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
        cpu_load_total,
        sampler.samples,
        hwm,
        threads_cpu,
    )
    _fill_instances(report, [figures[i.instance] for i in services], results)
    report.checkpoint_puts, report.checkpoint_bytes = wire_puts, wire_bytes
    report.checkpoint_zlib_ratio = wire_zlib
    report.takeover = takeover.as_dict() if takeover is not None else None
    report.router_cpu_load_s = router_cpu
    report.router_bytes_in, report.router_bytes_out = router_bytes
    baseline_streams = simulated_streams(
        spec, 0, spacing, robots=min(spec.baseline_robots, len(spec.robots_of(0)))
    )
    observe, apply, coalesced, frames = offline_baseline(
        baseline_streams, report.frames_per_decision, spec.method
    )
    report.baseline_observe_us = observe
    report.baseline_apply_us = apply
    report.baseline_coalesced_us = coalesced
    report.baseline_frames = frames
    report.baseline_robots = len(baseline_streams)
    return report


def _wait_partitions(
    services: Sequence[ServiceProcess | WorkerView], timeout_s: float
) -> dict[str, int]:
    """Wait until each instance owns its rendezvous share of the partitions; return it.

    Generators start only then, so no robot's first frames go to a partition nobody has
    subscribed to yet.
    """
    from lessmap_schemas.partition import assignment

    names = [i.instance for i in services]
    expected = {name: 0 for name in names}
    for owner, _standby in assignment(names).values():
        if owner is not None:
            expected[owner] += 1
    deadline = time.monotonic() + timeout_s
    while True:
        owned = {
            i.instance: parse_metrics(i.metrics_text()).get("lessmap_partitions_owned", 0.0)
            for i in services
        }
        if all(owned[name] == expected[name] for name in names):
            return expected
        if time.monotonic() > deadline:
            msg = f"partitions owned {owned}, expected {expected}"
            raise RuntimeError(msg)
        time.sleep(0.2)


class _CheckpointTap:
    """Counts the checkpoints the owners put for their standbys, and their bytes.

    Every tenth one is also compressed (zlib level 1, on this process's own thread) to show
    what compressing shipped checkpoints would save.
    """

    def __init__(self, session: zenoh.Session) -> None:
        from lessmap_schemas import keys

        self.puts = 0
        self.bytes = 0
        self.sampled = 0
        self.sampled_zlib = 0
        self._samples: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._compress, name="bench-zlib", daemon=True)
        self._thread.start()
        self._sub = session.declare_subscriber(keys.checkpoints(), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:  # Zenoh's thread: count only
        self.puts += 1
        self.bytes += len(sample.payload)
        if self.puts % 10 == 1:
            self._samples.put(sample.payload.to_bytes())

    def _compress(self) -> None:
        while (payload := self._samples.get()) is not None:
            self.sampled += len(payload)
            self.sampled_zlib += len(zlib.compress(payload, 1))

    def close(self) -> tuple[int, int, float]:
        """Stop; return (puts, bytes, zlib-1 size / raw size of the sampled ones)."""
        self._sub.undeclare()
        self._samples.put(None)
        self._thread.join(30.0)
        return self.puts, self.bytes, self.sampled_zlib / self.sampled if self.sampled else math.nan


def _fill_instances(
    report: LoadReport, figures: list[InstanceFigures], results: list[dict[str, Any]]
) -> None:
    """Give each instance the robots it owned at the start and the frames they offered."""
    from lessmap_schemas.partition import assignment, partition_of

    owners = assignment([f.name for f in figures])
    by_name = {f.name: f for f in figures}
    for result in results:
        for robot, times in zip(result["robots"], result["published_s"], strict=True):
            owner = owners[partition_of(report.spec.fleet, robot)][0]
            if owner in by_name:
                by_name[owner].robots += 1
                by_name[owner].frames_offered += len(times)
    report.instance_figures = figures


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
        process = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.fleet.orchestrate", str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log,
            cwd=REPO_ROOT,  # the generator runs as `python -m benchmarks.fleet...`
        )
    if spec.pin_generators:
        # Before its Zenoh threads start (it imports and simulates first); they inherit it.
        os.sched_setaffinity(process.pid, {max(os.sched_getaffinity(0))})
    return process


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
    # After a kill the new owner applies again what the victim applied after its last
    # checkpoint, and the victim's counter is gone: the two sums differ by design.
    if counted != report.applied and spec.kill_after_s is None:
        report.notes.append(
            f"lessmap_frames_applied_total {counted:.0f} != states {report.applied}"
        )
    if report.late_frames:
        report.notes.append(
            "the generators fell behind schedule: the offered rate is below "
            "nominal (CPU shared with the service, or Zenoh back-pressure)"
        )
    return report


if __name__ == "__main__":
    sys.exit(generator_main(sys.argv[1]))

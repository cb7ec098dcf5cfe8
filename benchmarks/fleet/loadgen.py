"""The load generator of the fleet load benchmark: specs, simulated streams, paced publishing.

One generator process (``python -m benchmarks.fleet.orchestrate SPEC.json``) opens one
client Zenoh session and one ``RobotPublisher`` per robot, paced in real time (robot i
of N publishes frame k at ``t0 + k/R + i/(N R)``: phases spread evenly over the period).

Streams come from the seeded building simulator (``lessmap.sim.simulator``); the
features-per-frame target F is met by landmark density (``calibrate_spacing``). Generator g
simulates its robots in its own building (seed ``1000 * seed + g``).
"""

from __future__ import annotations

import json
import select
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

_CALIBRATION_FRAMES = 200
_DEFAULT_SPACING_M = 0.6  # the sim's landmark spacing is drawn in (a, 2a); default a = 0.6
# Enough robots that a second of the core's CPU is timed (4 gave ~0.2 s: noisy), few enough
# that the baseline stays a few seconds; the per-frame cost hardly moves with the count.
_BASELINE_ROBOTS = 25
_EARLY_S = 0.002  # a frame may leave this much before its time (robots are not in step)


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
    shards: int | None = None  # service shards per instance (None: the service default)
    # `serve --workers N`: one command, N instance processes on this host sharing the fleet.
    serve_workers: int = 1
    max_batch_frames: int | None = None  # None: the service default (coalescing on)
    batch_linger_ms: float | None = None  # None: the service default
    # Service processes sharing the fleet by partition ownership: 1 = one instance that is
    # its own router; N > 1 = a `lessmap router` and N instances joined to it as clients.
    instances: int = 1
    kill_after_s: float | None = None  # kill -9 one instance this long into the load
    memory_only: bool = False  # True: `serve --memory-only` (no session checkpoints)
    method: str | None = None  # `serve --method` (None: the service default, areas)
    # True: the generators run on the last CPU only. Robots publish from their own machines;
    # here they time-slice with the service on both cores and slow it by evicting its caches.
    pin_generators: bool = False
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
    from lessmap.sim.simulator import simulate

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
    from lessmap.sim.simulator import simulate

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
    """Run one load generator (``python -m benchmarks.fleet.orchestrate SPEC.json``).

    Protocol on stdio: writes ``ready`` once its publishers are declared and the service is
    alive, reads the start time t0 (Unix seconds) as one line, publishes, ends every session,
    writes the results JSON to ``spec["out"]`` and exits.
    """
    from lessmap_client import RobotPublisher, close_all, open_session

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
                if delay > _EARLY_S:
                    # Frames due within _EARLY_S go out together. A wake-up per frame cost
                    # the generators 15.0-16.4 s of CPU for 150,000 frames (500 robots, 30 s)
                    # against 11.7 s, on the cores the service runs on.
                    time.sleep(delay)
                elif -delay > period:
                    late_frames += 1
                lateness_max = max(lateness_max, -delay)
                published[local].append(time.time())
                publisher.publish(streams[local][k], stamp_s=target)
        # Every SessionEnd (with last_seq: the service counts a lost tail) first, then one
        # wait for all the confirmations: one close after the other cost a latency per robot.
        close_all(publishers)
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


if __name__ == "__main__":
    sys.exit(generator_main(sys.argv[1]))

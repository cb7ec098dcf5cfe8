"""The live half of ``benchmarks.camera``: one camera robot against ``lessmap serve``.

A fresh ``lessmap serve`` with default settings (its state in a temporary folder, its
metrics on free ports, one per worker) takes a stream at its frame rate; the service's
``lessmap_frame_latency_seconds`` histograms (receipt of a frame to the end of the decision
covering it) give the share of frames decided within 20 ms and 100 ms, and the robot's
transitions are compared with the offline run's. Every process is stopped by its PID.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
import urllib.request
import uuid
from typing import TYPE_CHECKING, Any

from benchmarks.fleet.process import free_port, free_ports, stop_process
from lessmap_client import FleetClient, RobotPublisher
from lessmap_client.session import open_session

if TYPE_CHECKING:
    from lessmap.files.frames import FrameRow
    from lessmap_schemas.messages import Transition

_HISTOGRAM = "lessmap_frame_latency_seconds"
_BUCKET = re.compile(_HISTOGRAM + r'_bucket\{[^}]*le="([^"]+)"[^}]*\} ([0-9.e+]+)')
_APPLIED = re.compile(r"^lessmap_frames_applied_total(?:\{[^}]*\})? ([0-9.e+]+)", re.M)
_WORKERS = 2  # serve's default on this benchmark's 2-core hosts; the ports of up to this many


def scrape(ports: list[int]) -> tuple[dict[float, float], float]:
    """Sum the frame latency buckets and the applied frames over the workers' /metrics."""
    buckets: dict[float, float] = {}
    applied = 0.0
    for port in ports:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as page:
                text = page.read().decode()
        except OSError:
            continue  # fewer workers than ports
        for bound, count in _BUCKET.findall(text):
            buckets[float(bound)] = buckets.get(float(bound), 0.0) + float(count)
        applied += sum(float(v) for v in _APPLIED.findall(text))
    return buckets, applied


def share_within(buckets: dict[float, float], bound_s: float) -> float:
    """The share of frames decided within ``bound_s`` (a bucket's bound)."""
    total = buckets.get(float("inf"), 0.0)
    return buckets.get(bound_s, float("nan")) / total if total else float("nan")


def quantile_ms(buckets: dict[float, float], q: float) -> float:
    """A quantile interpolated within its bucket, as Prometheus' histogram_quantile does."""
    total = buckets.get(float("inf"), 0.0)
    lower, below = 0.0, 0.0
    for bound in sorted(buckets):
        count = buckets[bound]
        if count >= q * total and total:
            if bound == float("inf"):
                return 1000.0 * lower
            return 1000.0 * (lower + (bound - lower) * (q * total - below) / (count - below))
        lower, below = bound, count
    return float("nan")


def live(
    frames: list[FrameRow], rate_hz: float, expected: list[tuple[int, int, int | None]]
) -> dict[str, Any]:
    """Publish ``frames`` at ``rate_hz`` to a fresh default ``serve``; return its figures."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    first = free_ports(_WORKERS)
    ports = list(range(first, first + _WORKERS))
    got: list[tuple[int, int, int | None]] = []
    with tempfile.TemporaryDirectory(prefix="lessmap-camera-") as state:
        args = [sys.executable, "-m", "lessmap", "serve", "-m", "router", "-l", endpoint]
        args += ["--cfg", "scouting/multicast/enabled:false", "--state-dir", state]
        args += ["--metrics-port", str(first)]
        service = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        session = open_session([endpoint], timeout_s=30.0)
        fleet = f"camera-{uuid.uuid4().hex[:8]}"
        robot_name = frames[0].robot
        try:
            with FleetClient(fleet, robot_name, session=session) as client:

                def on_transition(t: Transition) -> None:
                    got.append((t.boundary_seq, t.area, t.left_area if t.revisit else None))

                client.on_transition(on_transition)
                with RobotPublisher(fleet, robot_name, session=session) as robot:
                    if not robot.wait_for_service(30.0):
                        msg = "the service did not come up"
                        raise RuntimeError(msg)
                    start = time.monotonic()
                    for index, frame in enumerate(frames):
                        delay = start + index / rate_hz - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                        robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
                    deadline = time.monotonic() + 120.0
                    buckets, applied = scrape(ports)
                    while applied < len(frames) and time.monotonic() < deadline:
                        time.sleep(0.5)
                        buckets, applied = scrape(ports)
                    time.sleep(1.0)  # the last transitions on their way
        finally:
            session.close()
            stop_process(service)
    return {
        "frames": len(frames),
        "applied": applied,
        "within_20ms": share_within(buckets, 0.02),
        "within_100ms": share_within(buckets, 0.1),
        "p50_ms": quantile_ms(buckets, 0.5),
        "p99_ms": quantile_ms(buckets, 0.99),
        "transitions": len(got),
        "offline_transitions": len(expected),
        "same_boundaries": [g[0] for g in got] == [e[0] for e in expected],
    }


def print_live(name: str, rate_hz: float, r: dict[str, Any]) -> None:
    """One line of live figures."""
    print(
        f"live, lessmap serve with default settings, {name} at {rate_hz:g} frames/s: "
        f"{r['applied']:.0f}/{r['frames']} frames applied; decided within 20 ms "
        f"{100 * r['within_20ms']:.1f}%, within 100 ms {100 * r['within_100ms']:.1f}% "
        f"(p50 ~{r['p50_ms']:.1f} ms, p99 ~{r['p99_ms']:.1f} ms, interpolated in buckets); "
        f"transitions {r['transitions']} (offline {r['offline_transitions']}), "
        f"same boundaries as offline: {r['same_boundaries']}"
    )

"""Noisy neighbours: a well-behaved robot's publish->transition latency beside abusive ones.

Run from the repository root: ``python -m benchmarks.noisy_neighbour``. It starts one
``lessmap serve`` (default settings, memory-only) per scenario on a loopback port, streams
the DLR data set as robot ``good`` at ``--rate`` frames/s and measures, for each transition,
the time from the publish of the frame it was decided at to its receipt. Scenarios:

- ``alone``: the good robot only;
- ``bad``: plus four 4096-feature overlapping frames (sampled to ``max_features_kept`` by
  the default method; the paper's ``max_pairs_per_frame`` refuses them);
- ``heavy``: plus a robot putting 600-feature frames (within budget) at 20 frames/s.

It prints p50/p99/max per scenario, the ratio to ``alone``, whether the good robot's
transitions equal ``lessmap segment``'s, and the service's peak RSS above its idle RSS.
Every process is stopped by its PID.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import uuid
from pathlib import Path

import zenoh

from benchmarks.fleet.process import free_port, stop_process
from lessmap.cli.segment import segment
from lessmap.core import PartitionParams
from lessmap.files.frames import read_frames
from lessmap_client import FleetClient, RobotPublisher
from lessmap_client.session import open_session
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.messages import Frame, Transition

REPO = Path(__file__).resolve().parents[1]
DLR = REPO / ".." / "shared" / "datasets" / "dlr.frames.jsonl"


def _vm_kib(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


def _pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


def run(scenario: str, rate_hz: float) -> dict[str, float | bool]:
    """Run one scenario against a fresh service; return its figures."""
    import subprocess

    frames = list(read_frames(DLR))
    expected: list[int] = []
    segment(
        frames,
        PartitionParams.from_profile("laser"),
        on_transition=lambda _robot, t: expected.append(t.seq),
    )
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    args = [sys.executable, "-m", "lessmap", "serve", "-m", "router", "-l", endpoint]
    args += ["--cfg", "scouting/multicast/enabled:false", "--memory-only"]
    service = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    fleet = f"nn-{uuid.uuid4().hex[:8]}"
    session = open_session([endpoint], timeout_s=20.0)
    stop = threading.Event()
    try:
        published: dict[int, float] = {}
        latencies: list[float] = []
        got: list[int] = []
        with FleetClient(fleet, "good", session=session) as client:

            def on_transition(t: Transition) -> None:
                got.append(t.seq)
                latencies.append(time.monotonic() - published[t.seq])

            client.on_transition(on_transition)
            with RobotPublisher(fleet, "good", session=session) as robot:
                if not robot.wait_for_service(20.0):
                    msg = "the service did not come up"
                    raise RuntimeError(msg)
                time.sleep(0.5)
                idle_kib = _vm_kib(service.pid, "VmRSS")
                loader = threading.Thread(target=_abuse, args=(scenario, session, fleet, stop))
                loader.start()
                start = time.monotonic()
                for index, frame in enumerate(frames):
                    delay = start + index / rate_hz - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    published[frame.seq] = time.monotonic()
                    robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
                stop.set()
                loader.join(30)
            deadline = time.monotonic() + 60
            while len(got) < len(expected) and time.monotonic() < deadline:
                time.sleep(0.1)
            time.sleep(1.0)
        peak_kib = _vm_kib(service.pid, "VmHWM")
    finally:
        stop.set()
        session.close()
        stop_process(service)
    return {
        "p50_ms": 1000 * _pct(latencies, 0.50),
        "p99_ms": 1000 * _pct(latencies, 0.99),
        "max_ms": 1000 * max(latencies, default=float("nan")),
        "exact": got == expected,
        "peak_over_idle_mib": (peak_kib - idle_kib) / 1024,
    }


def _abuse(scenario: str, session: zenoh.Session, fleet: str, stop: threading.Event) -> None:
    key = keys.frames(fleet, "noisy")
    block = zenoh.CongestionControl.BLOCK
    if scenario == "bad":
        stop.wait(1.0)
        for seq in range(4):
            features = list(range(seq * 1024, seq * 1024 + 4096))
            frame = Frame(session="b1", seq=seq, stamp_s=float(seq), features=features)
            session.put(key, encode(frame), congestion_control=block)
    elif scenario == "heavy":
        seq = 0
        while not stop.is_set():
            features = list(range(seq * 300, seq * 300 + 600))
            frame = Frame(session="h1", seq=seq, stamp_s=float(seq), features=features)
            session.put(key, encode(frame), congestion_control=block)
            seq += 1
            stop.wait(0.05)


def main() -> None:
    """Run the scenarios and print them side by side."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=200.0, help="good robot frames/s")
    parser.add_argument("--scenarios", default="alone,bad,heavy")
    args = parser.parse_args()
    results = {name: run(name, args.rate) for name in args.scenarios.split(",")}
    base = results.get("alone")
    header = f"{'scenario':<8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'p99 x':>6}"
    print(header + " exact  peak-idle MiB")
    for name, r in results.items():
        ratio = float(r["p99_ms"]) / float(base["p99_ms"]) if base else float("nan")
        print(
            f"{name:<8} {r['p50_ms']:>8.1f} {r['p99_ms']:>8.1f} {r['max_ms']:>8.1f} "
            f"{ratio:>6.2f} {r['exact']!s:<6} {r['peak_over_idle_mib']:>8.0f}"
        )


if __name__ == "__main__":
    main()

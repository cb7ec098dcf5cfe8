"""Isolation: an ordinary robot's publish->transition latency beside heavy robots or a slow app.

``python -m benchmarks.isolation``: per scenario a fresh ``lessmap serve`` (memory-only, one
shard, the paper's method) on loopback; robot ``good`` streams DLR at ``--rate`` frames/s.
Scenarios: ``alone``; ``heavy-old``/``heavy``: plus eight robots of 600-feature frames at
``--heavy-rate`` each, heavy lane off (``--heavy-decision-ms 0``) / on; ``slow``: plus an
app (own process) whose callback on every lessmap key never returns; ``slow-heavy-old`` /
``slow-heavy``: slow app and heavy robots, without / with the routers' drop toward slow
consumers (its link then fills within seconds).

Prints p50/p99/max of the good robot's latencies, the p99 ratio to ``alone``, whether its
transitions equal ``lessmap segment``'s, and the 1-minute load average before and after
(the host is shared). Every process is stopped by its PID.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import zenoh

from benchmarks.fleet.process import free_port, stop_process
from lessmap.cli.segment import segment
from lessmap.config.settings import ServiceSettings
from lessmap.files.frames import read_frames
from lessmap_client import FleetClient, RobotPublisher
from lessmap_client.session import open_session
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.messages import Frame, Transition

REPO = Path(__file__).resolve().parents[1]
DLR = REPO / ".." / "shared" / "datasets" / "dlr.frames.jsonl"
HEAVY_ROBOTS = 8
HEAVY_FEATURES = 600
_NO_QOS = '[{id:"none",messages:["put"],key_exprs:["nothing/**"],overwrite:{}}]'


def _pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


def run(scenario: str, rate_hz: float, heavy_rate_hz: float) -> dict[str, float | bool]:
    """Run one scenario against a fresh service; return its figures."""
    frames = list(read_frames(DLR))
    expected: list[int] = []
    segment(
        frames,
        ServiceSettings(memory_only=True, method="paper").partition_params(),
        on_transition=lambda _robot, t: expected.append(t.seq),
    )
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    args = [sys.executable, "-m", "lessmap", "serve", "-m", "router", "-l", endpoint]
    args += ["--cfg", "scouting/multicast/enabled:false", "--memory-only", "--method", "paper"]
    if scenario.endswith("-old") and scenario.startswith("slow"):
        # A rule that matches nothing replaces the default drop toward slow consumers.
        args += ["--cfg", f"qos/network:{_NO_QOS}"]
    if scenario == "heavy-old":
        args += ["--heavy-decision-ms", "0"]
    load_before = os.getloadavg()[0]
    service = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    fleet = f"iso-{uuid.uuid4().hex[:8]}"
    session = open_session([endpoint], timeout_s=20.0)
    app = _slow_app(endpoint) if scenario.startswith("slow") else None
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
                loader = threading.Thread(
                    target=_heavy, args=(scenario, session, fleet, heavy_rate_hz, stop)
                )
                loader.start()
                start = time.monotonic()
                for index, frame in enumerate(frames):
                    delay = start + index / rate_hz - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    published[frame.seq] = time.monotonic()
                    robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
                deadline = time.monotonic() + 60
                while len(got) < len(expected) and time.monotonic() < deadline:
                    time.sleep(0.1)
                stop.set()
                loader.join(30)
    finally:
        stop.set()
        if app is not None:
            stop_process(app)
        session.close()
        stop_process(service)
    return {
        "p50_ms": 1000 * _pct(latencies, 0.50),
        "p99_ms": 1000 * _pct(latencies, 0.99),
        "max_ms": 1000 * max(latencies, default=float("nan")),
        "exact": got == expected,
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
    }


# An app whose callback never returns: Zenoh's receiving thread in it is stuck from the first
# sample on, so its link from the router fills. Its own process, as an app's would be (a
# blocked callback in this one would also starve this process's other sessions).
_SLOW_APP = """
import sys, threading, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", '["%s"]' % sys.argv[1])
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
session.declare_subscriber(sys.argv[2], lambda _sample: threading.Event().wait())
print("ready", flush=True)
threading.Event().wait()
"""


def _slow_app(endpoint: str) -> subprocess.Popen[bytes]:
    args = [sys.executable, "-c", _SLOW_APP, endpoint, f"{keys.KEY_PREFIX}/**"]
    app = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    assert app.stdout is not None
    app.stdout.readline()  # "ready": declared
    return app


def _heavy(
    scenario: str, session: zenoh.Session, fleet: str, rate_hz: float, stop: threading.Event
) -> None:
    """Eight robots of 600-feature frames, half shared with the frame before (heavy only)."""
    if "heavy" not in scenario:
        return
    congestion = zenoh.CongestionControl.BLOCK  # as the SDK's robots put frames
    robots = [keys.frames(fleet, f"heavy{index}") for index in range(HEAVY_ROBOTS)]
    seq = 0
    start = time.monotonic()
    while not stop.is_set():
        half = HEAVY_FEATURES // 2
        features = list(range(seq * half, seq * half + HEAVY_FEATURES))
        frame = Frame(session="h1", seq=seq, stamp_s=float(seq), features=features)
        payload = encode(frame)
        for key in robots:
            session.put(key, payload, congestion_control=congestion)
        seq += 1
        stop.wait(max(0.0, start + seq / rate_hz - time.monotonic()))


def main() -> None:
    """Run the scenarios and print them side by side."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=200.0, help="good robot frames/s")
    parser.add_argument("--heavy-rate", type=float, default=20.0, help="each heavy robot's")
    parser.add_argument(
        "--scenarios", default="alone,heavy-old,heavy,slow,slow-heavy-old,slow-heavy"
    )
    args = parser.parse_args()
    results = {name: run(name, args.rate, args.heavy_rate) for name in args.scenarios.split(",")}
    base = results.get("alone")
    print(f"{'scenario':<10} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'p99 x':>6} exact  load")
    for name, r in results.items():
        ratio = float(r["p99_ms"]) / float(base["p99_ms"]) if base else float("nan")
        print(
            f"{name:<10} {r['p50_ms']:>8.1f} {r['p99_ms']:>8.1f} {r['max_ms']:>8.1f} "
            f"{ratio:>6.2f} {r['exact']!s:<6} {r['load_before']:.1f}->{r['load_after']:.1f}"
        )
    old, new = results.get("heavy-old"), results.get("heavy")
    if old and new:
        print(
            f"heavy lane: p99 {float(old['p99_ms']):.0f} -> {float(new['p99_ms']):.0f} ms "
            f"({float(old['p99_ms']) / float(new['p99_ms']):.1f}x lower)"
        )


if __name__ == "__main__":
    main()

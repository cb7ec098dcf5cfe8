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
import subprocess
import sys
import threading
import time

import zenoh

from benchmarks.good_robot import run_good_robot
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.messages import Frame

HEAVY_ROBOTS = 8
HEAVY_FEATURES = 600
_NO_QOS = '[{id:"none",messages:["put"],key_exprs:["nothing/**"],overwrite:{}}]'


def run(scenario: str, rate_hz: float, heavy_rate_hz: float) -> dict[str, float | bool | str]:
    """Run one scenario against a fresh service; return its figures."""
    args: list[str] = []
    if scenario.endswith("-old") and scenario.startswith("slow"):
        # A rule that matches nothing replaces the default drop toward slow consumers.
        args += ["--cfg", f"qos/network:{_NO_QOS}"]
    if scenario == "heavy-old":
        args += ["--heavy-decision-ms", "0"]
    measured = run_good_robot(
        "paper",
        lambda session, fleet, stop: _heavy(scenario, session, fleet, heavy_rate_hz, stop),
        rate_hz=rate_hz,
        fleet_prefix="iso",
        serve_args=tuple(args),
        beside=_slow_app if scenario.startswith("slow") else lambda _endpoint: None,
    )
    return measured.figures()


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
    columns = f"{'scenario':<10} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'p99 x':>6}"
    print(columns + " exact  coalesced  load")
    for name, r in results.items():
        ratio = float(r["p99_ms"]) / float(base["p99_ms"]) if base else float("nan")
        print(
            f"{name:<10} {r['p50_ms']:>8.1f} {r['p99_ms']:>8.1f} {r['max_ms']:>8.1f} "
            f"{ratio:>6.2f} {r['exact']!s:<6} {r['coalesced']:>9} "
            f"{r['load_before']:.1f}->{r['load_after']:.1f}"
        )
    old, new = results.get("heavy-old"), results.get("heavy")
    if old and new:
        print(
            f"heavy lane: p99 {float(old['p99_ms']):.0f} -> {float(new['p99_ms']):.0f} ms "
            f"({float(old['p99_ms']) / float(new['p99_ms']):.1f}x lower)"
        )
    for name, r in results.items():
        if r["difference"]:
            print(f"{name}: the transitions differ from the offline run's: {r['difference']}")


if __name__ == "__main__":
    main()

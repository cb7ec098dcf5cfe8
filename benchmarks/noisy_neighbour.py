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
import threading

import zenoh

from benchmarks.good_robot import run_good_robot
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.messages import Frame


def run(scenario: str, rate_hz: float) -> dict[str, float | bool | str]:
    """Run one scenario against a fresh service (default settings); return its figures."""
    measured = run_good_robot(
        "areas",  # the default method
        lambda session, fleet, stop: _abuse(scenario, session, fleet, stop),
        rate_hz=rate_hz,
        fleet_prefix="nn",
        others_until_done=False,
    )
    return measured.figures()


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
    print(header + " exact  coalesced  peak-idle MiB")
    for name, r in results.items():
        ratio = float(r["p99_ms"]) / float(base["p99_ms"]) if base else float("nan")
        print(
            f"{name:<8} {r['p50_ms']:>8.1f} {r['p99_ms']:>8.1f} {r['max_ms']:>8.1f} "
            f"{ratio:>6.2f} {r['exact']!s:<6} {r['coalesced']:>9} {r['peak_over_idle_mib']:>8.0f}"
        )
    for name, r in results.items():
        if r["difference"]:
            print(f"{name}: the transitions differ from the offline run's: {r['difference']}")


if __name__ == "__main__":
    main()

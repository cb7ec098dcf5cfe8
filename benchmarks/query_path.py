"""One robot's ``state`` query among many sessions: named exactly, and by a wildcard.

Run from the repository root: ``python -m benchmarks.query_path``. It starts one
``lessmap serve`` (memory-only, its embedded router on a random free loopback port), opens
``--robots`` sessions of one frame each, then asks one robot's state ``--queries`` times
with its key written out (``lessmap/v4/<fleet>/solo/state``: the service answers from that
robot's shard alone) and as many times by a wildcard that only that robot matches
(``.../so$*/state``: every robot of every shard is checked against the selector, as every
query was before the named path existed). Printed: the median and p90 round trip of each,
and their ratio, measured in the same run against the same service. The process is stopped
by its PID.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import zenoh

from benchmarks.fleet.process import free_port, stop_process
from lessmap_client.session import open_session, wait_for_service
from lessmap_schemas import keys
from lessmap_schemas.codec import decode, encode
from lessmap_schemas.messages import Frame, SessionState

BLOCK = zenoh.CongestionControl.BLOCK  # a burst of puts must not be dropped at the sender


def _frame(robot: int) -> bytes:
    features = [robot * 10 + k for k in range(8)]
    return encode(Frame(session="s1", seq=0, stamp_s=0.0, features=features))


def _ask(session: zenoh.Session, key: str) -> float:
    """Seconds until the one robot's state came back (raises if it did not)."""
    start = time.perf_counter()
    samples = [r.ok for r in session.get(key, timeout=10.0) if r.ok is not None]
    took = time.perf_counter() - start
    if len(samples) != 1:
        msg = f"{key}: {len(samples)} replies, expected 1"
        raise RuntimeError(msg)
    state = decode(samples[0].payload.to_bytes(), SessionState)
    if state.robot != "solo":
        msg = f"{key}: answered for {state.robot!r}"
        raise RuntimeError(msg)
    return took


def _fill(session: zenoh.Session, fleet: str, robots: int) -> None:
    """Open ``robots`` one-frame sessions and "solo"; return once the last one answers."""
    for robot in range(robots):
        key = keys.frames(fleet, f"r{robot}")
        session.put(key, _frame(robot), congestion_control=BLOCK)
    session.put(keys.frames(fleet, "solo"), _frame(robots), congestion_control=BLOCK)
    deadline = time.monotonic() + 120.0
    while not any(r.ok is not None for r in session.get(keys.state(fleet, "solo"), timeout=2.0)):
        if time.monotonic() > deadline:
            msg = "the sessions were not all open within 120 s"
            raise RuntimeError(msg)
        time.sleep(0.1)


def run(robots: int, queries: int) -> tuple[list[float], list[float]]:
    """Return the round trips of the named and of the wildcard queries."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fleet = f"q{uuid.uuid4().hex[:8]}"
    args = [sys.executable, "-m", "lessmap", "serve", "--memory-only", "-l", endpoint]
    args += ["--new-sessions-per-s-per-fleet", str(10 * robots)]  # the flood is the point
    with tempfile.TemporaryDirectory() as tmp, Path(tmp, "serve.log").open("wb") as log:
        service = subprocess.Popen(args, stdout=log, stderr=log)
        try:
            session = open_session(connect=[endpoint])
            try:
                if not wait_for_service(session, 30.0):
                    msg = "the service did not come up in 30 s"
                    raise RuntimeError(msg)
                _fill(session, fleet, robots)
                named = keys.state(fleet, "solo")
                wildcard = named.replace("/solo/", "/so$*/")
                times: dict[str, list[float]] = {named: [], wildcard: []}
                for _ in range(queries):  # interleaved, so both see the same machine
                    for key in times:
                        times[key].append(_ask(session, key))
                return times[named], times[wildcard]
            finally:
                session.close()
        finally:
            stop_process(service)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=5000, help="sessions open (default 5000)")
    parser.add_argument("--queries", type=int, default=200, help="queries of each kind")
    args = parser.parse_args()
    named, wildcard = run(args.robots, args.queries)

    for name, values in (("named", named), ("wildcard", wildcard)):
        median = 1e3 * statistics.median(values)
        p90 = 1e3 * statistics.quantiles(values, n=10)[-1]
        print(f"{name:9} median {median:7.2f} ms   p90 {p90:7.2f} ms")
    ratio = statistics.median(wildcard) / statistics.median(named)
    print(f"wildcard / named (median): {ratio:.1f}x at {args.robots} sessions")


if __name__ == "__main__":
    main()

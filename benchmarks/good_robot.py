"""One well-behaved robot beside others: the run that ``isolation`` and ``noisy_neighbour`` share.

``run_good_robot`` starts a ``lessmap serve`` (the given arguments, on a free loopback port),
streams the DLR data set as robot ``good`` at a fixed rate while a loader thread puts the
scenario's other traffic, and returns the good robot's publish -> Transition latencies,
whether its transitions equal ``lessmap segment``'s, the service's RSS when idle and at its
peak, and the load average before and after (the host is shared). Every process it starts
is stopped by its PID.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from benchmarks.fleet.process import free_port, proc_status_kib, stop_process
from lessmap.cli.app import command_parser
from lessmap.cli.segment import segment, segment_areas
from lessmap.config.settings import ServiceSettings, settings_from_args
from lessmap.core.areas.tracker import AreaParams
from lessmap.files.frames import read_frames
from lessmap.runtime.workers import worker_count
from lessmap_client import FleetClient, RobotPublisher
from lessmap_client.session import open_session
from lessmap_schemas import keys

if TYPE_CHECKING:
    import zenoh

    from lessmap_schemas.messages import Transition

REPO = Path(__file__).resolve().parents[1]
DLR = REPO / ".." / "shared" / "datasets" / "dlr.frames.jsonl"

#: The other traffic of a scenario: (session, fleet, stop) -> returns once ``stop`` is set.
Loader = Callable[["zenoh.Session", str, threading.Event], None]


def percentile_ms(seconds: list[float], q: float) -> float:
    """The nearest-rank ``q`` quantile of latencies in seconds, in ms (NaN if none)."""
    if not seconds:
        return float("nan")
    return 1000 * float(np.quantile(seconds, q, method="inverted_cdf"))


def first_difference(expected: list[int], got: list[int]) -> str:
    """Where two lists of transition seqs first differ, in words ("" when equal)."""
    if got == expected:
        return ""
    pairs = enumerate(zip(expected, got, strict=False))
    at = next((i for i, (e, g) in pairs if e != g), min(len(expected), len(got)))
    wanted = expected[at] if at < len(expected) else None
    found = got[at] if at < len(got) else None
    return f"{len(got)} transitions, offline {len(expected)}; #{at}: seq {found}, offline {wanted}"


def serve_workers(serve_args: list[str]) -> int:
    """How many workers ``lessmap serve SERVE_ARGS`` runs: its own flags and settings decide."""
    parser, _run = command_parser("serve")
    parsed = parser.parse_args(serve_args)
    return worker_count(settings_from_args(parsed, parsed.settings_flags))


def wait_for_workers(session: zenoh.Session, count: int, timeout_s: float) -> None:
    """Wait until ``count`` service instances declare their tokens; raise after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        replies = session.liveliness().get(keys.instances(), timeout=1.0)
        live = sum(1 for reply in replies if reply.ok is not None)
        if live >= count:
            return
        if time.monotonic() > deadline:
            msg = f"{live} of {count} service worker(s) up after {timeout_s:.0f} s"
            raise RuntimeError(msg)
        time.sleep(0.2)


@dataclass(frozen=True, slots=True)
class GoodRun:
    """What one scenario measured of the good robot and the service."""

    latencies_s: list[float]
    exact: bool
    # Transitions decided over more than one frame: the service coalesced the robot's frames
    # (it lagged), so its decisions may differ from the per-frame offline run's.
    coalesced: int
    difference: str  # where the transitions first differ from the offline run's ("" if none)
    idle_kib: int
    peak_kib: int
    load_before: float
    load_after: float

    def figures(self) -> dict[str, float | bool | str]:
        """p50/p99/max in ms, exactness, peak RSS over idle and the load averages."""
        return {
            "p50_ms": percentile_ms(self.latencies_s, 0.50),
            "p99_ms": percentile_ms(self.latencies_s, 0.99),
            "max_ms": 1000 * max(self.latencies_s, default=float("nan")),
            "exact": self.exact,
            "coalesced": self.coalesced,
            "difference": self.difference,
            "peak_over_idle_mib": (self.peak_kib - self.idle_kib) / 1024,
            "load_before": self.load_before,
            "load_after": self.load_after,
        }


def run_good_robot(
    method: str,
    loader: Loader,
    *,
    rate_hz: float,
    fleet_prefix: str,
    serve_args: tuple[str, ...] = (),
    beside: Callable[[str], subprocess.Popen[bytes] | None] = lambda _endpoint: None,
    others_until_done: bool = True,
) -> GoodRun:
    """Run one scenario against a fresh service of ``method`` ("paper" or "areas").

    ``beside``: a process started with it; ``others_until_done``: the loader keeps going
    until the good robot's last transition is in (False: it stops at its last publish).
    """
    frames = list(read_frames(DLR))
    expected: list[int] = []
    if method == "paper":  # the service's paper parameters, as `lessmap segment` runs them
        params = ServiceSettings(memory_only=True, method="paper").partition_params()
        segment(frames, params, on_transition=lambda _robot, t: expected.append(t.seq))
    else:
        segment_areas(frames, AreaParams(), lambda _robot, c: expected.append(c.transition.seq))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    options = ["-m", "router", "-l", endpoint, "--cfg", "scouting/multicast/enabled:false"]
    options += ["--memory-only", "--method", method, *serve_args]
    args = [sys.executable, "-m", "lessmap", "serve", *options]
    load_before = os.getloadavg()[0]
    service = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    other: subprocess.Popen[bytes] | None = None
    fleet = f"{fleet_prefix}-{uuid.uuid4().hex[:8]}"
    session = open_session([endpoint], timeout_s=20.0)
    stop = threading.Event()
    published: dict[int, float] = {}
    latencies: list[float] = []
    got: list[int] = []
    coalesced: list[int] = []
    try:
        other = beside(endpoint)
        with FleetClient(fleet, "good", session=session) as client:

            def on_transition(t: Transition) -> None:
                got.append(t.seq)
                if t.batch_frames > 1:
                    coalesced.append(t.seq)
                latencies.append(time.monotonic() - published[t.seq])

            client.on_transition(on_transition)
            with RobotPublisher(fleet, "good", session=session) as robot:
                if not robot.wait_for_service(20.0):
                    msg = "the service did not come up"
                    raise RuntimeError(msg)
                # serve starts its workers one after another; a robot that starts before the
                # last has joined sees its session moved (with --memory-only, restarted)
                wait_for_workers(session, serve_workers(options), 30.0)
                time.sleep(0.5)
                idle_kib = proc_status_kib(service.pid, "VmRSS")
                traffic = threading.Thread(target=loader, args=(session, fleet, stop))
                traffic.start()
                start = time.monotonic()
                for index, frame in enumerate(frames):
                    delay = start + index / rate_hz - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    published[frame.seq] = time.monotonic()
                    robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
                if not others_until_done:
                    stop.set()
                deadline = time.monotonic() + 60
                while len(got) < len(expected) and time.monotonic() < deadline:
                    time.sleep(0.1)
                stop.set()
                traffic.join(30)
        peak_kib = proc_status_kib(service.pid, "VmHWM")
    finally:
        stop.set()
        if other is not None:
            stop_process(other)
        session.close()
        stop_process(service)
    return GoodRun(
        latencies,
        got == expected,
        len(coalesced),
        first_difference(expected, got),
        idle_kib,
        peak_kib,
        load_before,
        os.getloadavg()[0],
    )

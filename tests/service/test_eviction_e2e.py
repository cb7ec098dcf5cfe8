"""Idle sessions go to the state store and give their memory back (a real ``lessmap serve``).

10,000 robots send one frame each and fall silent past the idle timeout: every session is
evicted and the service gives most of the wave's memory back. An evicted robot that speaks
again resumes its session (no SESSION_CLOSED, no gap).

Measured (``-s`` prints it; details in docs/BENCHMARKS.md "Session flood and memory",
``python -m benchmarks.session_flood``): 1.09-1.10 x before here (3 runs). ``lessmap serve``
runs on glibc's malloc with two arenas (``lessmap.runtime.memory``); once the store has written
the records of sessions that left, its writer collects (emptying CPython's free lists), clears
the type attribute cache and SQLite's page cache and trims the heap. What stays (+5-9 MiB) is
mostly blocks cached by the per-thread malloc caches of zenoh-python's callback threads. A new
robot is served (its state answers with its frame applied) a few ms after its first put;
printed, not asserted: wall-clock bounds are flaky on a shared machine.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.messages import Frame
from tests.conftest import ServeProcess, metric_value, new_robot_wait_s, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

pytestmark = pytest.mark.timeout(300)

ROBOTS = 10_000
#: Per wave under areas: two waves of half the robots (its sessions cost twice the paper's to
#: open, checkpoint and evict; the default test run stays short).
AREAS_ROBOTS = 5_000

BLOCK = zenoh.CongestionControl.BLOCK  # a burst of puts must not be dropped at the sender


#: What may stay after the wave, over the RSS before it. The paper's sessions (1.1 KB
#: checkpoints): measured 1.09-1.11 x (benchmark and this test). The areas method's (4.6 KB
#: checkpoints, twice the objects per session): 1.21 and 1.28 x in two runs of 10,000,
#: malloc's fragmentation after a bigger peak (tracemalloc shows no Python object left
#: behind); 1.14 and 1.17 x in waves of 5,000 (``AREAS_ROBOTS``), whose second wave then
#: added 1.3 and 3.5 MiB: it must reuse that memory, not add to it.
AFTER_OVER_BEFORE = {"paper": 1.25, "areas": 1.35}


@pytest.mark.parametrize("method", list(AFTER_OVER_BEFORE))
@pytest.mark.slow
def test_ten_thousand_idle_sessions_are_evicted_and_memory_returns(
    method: str,
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    robots = ROBOTS if method == "paper" else AREAS_ROBOTS
    service = serve(
        "--method",
        method,
        "--idle-timeout",
        "2",
        "--max-sessions",
        "20000",
        "--new-sessions-per-s-per-fleet",
        "100000",
        metrics=True,
    )
    session = client_session(service.endpoint)
    wait_until(lambda: "serving as" in service.log(), 30.0, "the service")

    def frame_of(robot: int, seq: int) -> bytes:
        features = [robot * 10 + k for k in range(8)]
        return encode(Frame(session="s1", seq=seq, stamp_s=float(seq), features=features))

    def scraped(name: str) -> float:
        # A scrape may time out while the flood keeps the service busy (seen at load 9):
        # that is "not yet" for a wait, not a failure.
        try:
            return metric_value(service.metrics(), name)
        except OSError:
            return -1.0

    # Warm the interpreter with a first wave (allocator arenas, codec caches), then measure.
    for robot in range(200):
        session.put(
            keys.frames(fleet_name, f"warm{robot}"), frame_of(robot, 0), congestion_control=BLOCK
        )
    wait_until(
        lambda: scraped("lessmap_sessions_evicted_total") >= 200,
        60.0,
        "the warm-up sessions evicted",
    )
    before_kib = service.rss_kib()

    def settled_rss() -> int:
        # The store writes the evicted sessions (and frees their snapshots) after the
        # eviction, then gives the memory back: wait until the RSS has not fallen for 3 s
        # (bounded), as a user would look at it. On a loaded machine the writer may take a
        # few seconds to get there: one quiet half second is not "settled".
        last = now = service.rss_kib()
        quiet = 0
        for _ in range(120):
            time.sleep(0.5)
            now = service.rss_kib()
            quiet = quiet + 1 if now >= last - 256 else 0
            last = min(last, now)
            if quiet >= 6:
                break
        return now  # the RSS now, not the lowest seen

    def wave(prefix: str, opened: int) -> tuple[int, int]:
        for robot in range(robots):
            session.put(
                keys.frames(fleet_name, f"{prefix}{robot}"),
                frame_of(robot, 0),
                congestion_control=BLOCK,
            )
        wait_until(
            lambda: scraped("lessmap_sessions_opened_total") >= opened,
            120.0,
            f"{robots} sessions opened",
        )
        peak = service.rss_kib()
        wait_until(
            lambda: scraped("lessmap_sessions_evicted_total") >= opened,
            120.0,
            f"{robots} sessions evicted",
        )
        assert metric_value(service.metrics(), "lessmap_sessions") == 0
        return peak, settled_rss()

    first_peak, first_after = wave("r", 200 + robots)
    # Right after the flood a new robot is served: its first frame is applied.
    wait_s = new_robot_wait_s(session, fleet_name, "newcomer", frame_of(1, 0), 10.0)
    print(  # noqa: T201 - the figures in the module docstring come from here
        f"RSS KiB: before {before_kib}, peak {first_peak}, after eviction {first_after} "
        f"({first_after / before_kib:.2f} x before); a new robot served after {wait_s:.3f} s"
    )
    assert wait_s == wait_s, "the new robot's frame was not applied within 10 s"  # not NaN
    # Most of the wave's memory comes back (malloc_trim after evictions on glibc's malloc).
    # Measured 0.11-0.16 of the peak's growth left; 0.94 before the trim after eviction.
    assert first_after - before_kib <= 0.5 * (first_peak - before_kib)
    # The durable-sessions bar is 1.2 x for the paper: this guard against a regression
    # leaves room for the spread, not for a new leak.
    assert first_after <= AFTER_OVER_BEFORE[method] * before_kib
    if method == "areas":
        second_peak, second_after = wave("s", 200 + 2 * robots + 1)
        print(f"second wave: peak {second_peak}, after eviction {second_after}")  # noqa: T201
        assert second_after <= first_after + 0.1 * (first_peak - before_kib)

    # An evicted robot speaks again: its session resumes where it stopped.
    session.put(keys.frames(fleet_name, "r7"), frame_of(7, 1), congestion_control=BLOCK)
    wait_until(
        lambda: scraped("lessmap_sessions_resumed_total") >= 1,
        30.0,
        "the evicted session resumed",
    )
    text = service.metrics()
    assert metric_value(text, "lessmap_frames_missing_total") == 0
    waves = 2 if method == "areas" else 1
    assert metric_value(text, "lessmap_frames_applied_total") == 200 + waves * robots + 2
    assert service.terminate() == 0

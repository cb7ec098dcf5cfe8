"""Idle sessions go to the state store and give their memory back (a real ``lessmap serve``).

10,000 robots send one frame each and fall silent past the idle timeout: every session is
evicted and the service gives most of the wave's memory back. An evicted robot that speaks
again resumes its session (no SESSION_CLOSED, no gap).

Measured on the development machine (``-s`` prints it): RSS 96 MiB before, 195 MiB at the
peak, 132-159 MiB after the eviction, i.e. not yet the 20 % the durable-sessions issue asks.
In-process without Zenoh, tracemalloc shows < 1 MiB of Python objects retained: the rest is
allocator fragmentation (and, in the service, Zenoh's per-key state); a second and third
wave of new robots grew the in-process remainder by 5 and 28 MiB.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.messages import Frame
from tests.conftest import ServeProcess, metric_value, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

pytestmark = pytest.mark.timeout(300)

ROBOTS = 10_000


def test_ten_thousand_idle_sessions_are_evicted_and_memory_returns(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    service = serve(
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

    # Warm the interpreter with a first wave (allocator arenas, codec caches), then measure.
    for robot in range(200):
        session.put(keys.frames(fleet_name, f"warm{robot}"), frame_of(robot, 0))
    wait_until(
        lambda: metric_value(service.metrics(), "lessmap_sessions_evicted_total") >= 200,
        60.0,
        "the warm-up sessions evicted",
    )
    before_kib = service.rss_kib()

    def wave(prefix: str, opened: int) -> tuple[int, int]:
        for robot in range(ROBOTS):
            session.put(keys.frames(fleet_name, f"{prefix}{robot}"), frame_of(robot, 0))
        wait_until(
            lambda: metric_value(service.metrics(), "lessmap_sessions_opened_total") >= opened,
            120.0,
            f"{ROBOTS} sessions opened",
        )
        peak = service.rss_kib()
        wait_until(
            lambda: metric_value(service.metrics(), "lessmap_sessions_evicted_total") >= opened,
            120.0,
            f"{ROBOTS} sessions evicted",
        )
        assert metric_value(service.metrics(), "lessmap_sessions") == 0
        return peak, service.rss_kib()

    first_peak, first_after = wave("r", 200 + ROBOTS)
    print(  # noqa: T201 - the figures in the module docstring come from here
        f"RSS KiB: before {before_kib}, peak {first_peak}, after eviction {first_after}"
    )
    # Most of the wave's memory comes back (malloc_trim after evictions; small initial
    # CovGraph matrices keep the peak down).
    # Measured 0.34-0.74 of the peak's growth left; 0.94 without the trim after eviction.
    assert first_after - before_kib <= 0.85 * (first_peak - before_kib)

    # An evicted robot speaks again: its session resumes where it stopped.
    session.put(keys.frames(fleet_name, "r7"), frame_of(7, 1))
    wait_until(
        lambda: metric_value(service.metrics(), "lessmap_sessions_resumed_total") >= 1,
        30.0,
        "the evicted session resumed",
    )
    text = service.metrics()
    assert metric_value(text, "lessmap_frames_missing_total") == 0
    assert metric_value(text, "lessmap_frames_applied_total") == 200 + ROBOTS + 1
    assert service.terminate() == 0

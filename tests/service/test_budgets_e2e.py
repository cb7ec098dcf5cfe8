"""Work budgets, fair scheduling and admission against a real ``lessmap serve`` on loopback.

Each test runs a well-behaved robot (DLR, paced like a fast sensor) beside an abusive one,
with the service's default coalescing, and compares the well-behaved robot's transitions
with ``lessmap segment``'s for its file: another robot's load must change none of them.
Nothing here asserts on speed; latency figures are in docs/BENCHMARKS.md
(``benchmarks/noisy_neighbour.py``).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap.files.frames import FrameRow, read_frames
from lessmap_client import FleetClient, RobotPublisher
from lessmap_schemas import keys
from lessmap_schemas.codec import decode, encode
from lessmap_schemas.messages import Error, Frame
from tests.conftest import ServeProcess, dataset, metric_value, wait_until
from tests.service.test_serve_e2e import (
    as_record,
    drain,
    offline_transitions,
    raw_put,
    wait_closed,
)

if TYPE_CHECKING:
    from collections.abc import Callable

pytestmark = pytest.mark.timeout(300)

GOOD_RATE_HZ = 200.0  # fast for a robot, slow enough that its own load never coalesces


def vm_kib(pid: int, field: str) -> int:
    """Return a memory field of /proc/<pid>/status (VmRSS, VmHWM) in KiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


def stream(robot: RobotPublisher, frames: list[FrameRow], rate_hz: float) -> None:
    """Publish frames at a steady rate (absolute schedule, so a stall does not add up)."""
    start = time.monotonic()
    for index, frame in enumerate(frames):
        delay = start + index / rate_hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)


class Errors:
    """Collect the Error events of a fleet."""

    def __init__(self, session: zenoh.Session, fleet: str) -> None:
        self.items: list[Error] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(keys.errors(fleet, "*"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.items.append(decode(sample.payload.to_bytes(), Error))

    def of(self, robot: str) -> list[Error]:
        with self._lock:
            return [e for e in self.items if e.robot == robot]

    def close(self) -> None:
        self._sub.undeclare()


@pytest.mark.slow
def test_oversized_pair_work_is_refused_and_the_good_robot_is_exact(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    expected = offline_transitions(frames)["0"]
    # Default coalescing and budgets; the paper, as the reference `offline_transitions`.
    service = serve("--method", "paper", metrics=True)
    session = client_session(service.endpoint)
    errors = Errors(session, fleet_name)
    bad_key = keys.frames(fleet_name, "bad")
    with FleetClient(fleet_name, "good", session=session) as client:
        with RobotPublisher(fleet_name, "good", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            idle_kib = vm_kib(service.process.pid, "VmRSS")

            def attack() -> None:
                time.sleep(1.0)  # in the middle of the good robot's stream
                for seq in range(4):
                    # 4096 features (the wire limit), 3/4 shared with the frame before.
                    features = list(range(seq * 1024, seq * 1024 + 4096))
                    frame = Frame(session="b1", seq=seq, stamp_s=float(seq), features=features)
                    raw_put(session, bad_key, encode(frame))

            attacker = threading.Thread(target=attack)
            attacker.start()
            stream(robot, frames, GOOD_RATE_HZ)
            attacker.join(30)
        wait_closed(client, fleet_name, "good", len(frames))
        got = drain(client)
        wait_until(lambda: len(errors.of("bad")) >= 4, 30.0, "four errors for the bad robot")
        bad = client.state("bad", fleet=fleet_name, timeout_s=5.0)
    peak_kib = vm_kib(service.process.pid, "VmHWM")
    errors.close()

    assert [as_record(t) for t in got] == expected
    assert errors.of("good") == []
    refusals = errors.of("bad")
    assert [e.seq for e in refusals] == [0, 1, 2, 3]
    assert {e.code.value for e in refusals} == {"LIMIT_EXCEEDED"}
    assert all("max_pairs_per_frame" in e.detail for e in refusals), refusals[0].detail
    # The frames never reached a CovGraph: the bad session exists, empty, every frame counted.
    assert bad is not None
    assert (bad.frames_applied, bad.frames_rejected, bad.nodes, bad.edges) == (0, 4, 0, 0)
    text = service.metrics()
    assert metric_value(text, "lessmap_frames_rejected_total", reason="LIMIT_EXCEEDED") == 4
    assert peak_kib - idle_kib < 500 * 1024, f"peak {peak_kib} KiB, idle {idle_kib} KiB"
    assert service.terminate() == 0


@pytest.mark.slow
def test_a_heavy_robot_within_budget_does_not_change_the_good_robots_segmentation(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    expected = offline_transitions(frames)["0"]
    service = serve("--method", "paper", metrics=True)  # as `offline_transitions`
    session = client_session(service.endpoint)
    errors = Errors(session, fleet_name)
    heavy_key = keys.frames(fleet_name, "heavy")
    stop = threading.Event()
    sent: list[int] = []

    def heavy() -> None:
        # 600 features a frame (179,700 pairs, within max_pairs_per_frame), half shared with
        # the frame before: the CovGraph grows towards max_edges_per_session and every
        # decision on it costs a good part of a second.
        seq = 0
        while not stop.is_set() and seq < 2000:
            features = list(range(seq * 300, seq * 300 + 600))
            frame = Frame(session="h1", seq=seq, stamp_s=float(seq), features=features)
            raw_put(session, heavy_key, encode(frame))
            sent.append(seq)
            seq += 1
            stop.wait(0.05)

    with FleetClient(fleet_name, "good", session=session) as client:
        with RobotPublisher(fleet_name, "good", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            loader = threading.Thread(target=heavy)
            loader.start()
            wait_until(lambda: len(sent) >= 20, 30.0, "the heavy robot to be under way")
            stream(robot, frames, GOOD_RATE_HZ)
            stop.set()
            loader.join(30)
        wait_closed(client, fleet_name, "good", len(frames))
        got = drain(client)
        heavy_state = client.state("heavy", fleet=fleet_name, timeout_s=5.0)
    errors.close()

    assert [as_record(t) for t in got] == expected
    assert all(t.batch_frames == 1 for t in got)
    assert errors.of("good") == []
    # The heavy robot was served too (its own frames may be coalesced or refused by budget).
    assert heavy_state is not None
    assert heavy_state.frames_applied > 0
    assert heavy_state.edges <= 1_000_000
    text = service.metrics()
    assert metric_value(text, "lessmap_decision_seconds_count") > len(expected)
    assert service.terminate() == 0


def test_a_session_flood_does_not_lock_out_a_new_robot(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    flood_fleet = f"{fleet_name}-flood"
    # A token bucket slow enough that even a flood slowed down by a busy machine outruns it
    # (with the defaults, 200/s after a burst of 2000, a flood at 126 puts/s was rightly
    # admitted whole, evicting idle sessions, and nothing was refused); its burst above
    # --max-sessions, so the shard fills and the newcomers below need evictions.
    service = serve(
        "--max-sessions",
        "1000",
        "--new-sessions-per-s-per-fleet",
        "20",
        "--new-sessions-burst",
        "1500",
        metrics=True,
    )
    session = client_session(service.endpoint)
    wait_until(lambda: "serving as" in service.log(), 30.0, "the service")
    errors = Errors(session, fleet_name)
    flood_errors = Errors(session, flood_fleet)
    one = encode(Frame(session="s1", seq=0, stamp_s=0.0, features=[1, 2, 3]))
    flood = 10_000
    for index in range(flood):
        raw_put(session, keys.frames(flood_fleet, f"f{index}"), one)

    def flood_handled() -> bool:
        text = service.metrics()
        opened = metric_value(text, "lessmap_sessions_opened_total")
        refused = metric_value(text, "lessmap_frames_rejected_total", reason="SESSION_LIMIT")
        return opened + refused >= flood

    wait_until(flood_handled, 120.0, "every flood frame opened a session or was refused")
    text = service.metrics()
    assert metric_value(text, "lessmap_sessions") <= 1000
    assert metric_value(text, "lessmap_frames_rejected_total", reason="SESSION_LIMIT") > 0
    time.sleep(1.2)  # the flood's sessions are now idle (evictable), the bucket refills

    frames = [Frame(session="n1", seq=s, stamp_s=float(s), features=[s, s + 1]) for s in range(20)]
    with FleetClient(fleet_name, session=session) as client:
        # A new robot of another fleet, and a late robot of the flooded fleet.
        for fleet, robot in ((fleet_name, "newcomer"), (flood_fleet, "late")):
            for frame in frames:
                raw_put(session, keys.frames(fleet, robot), encode(frame))
        for fleet, robot in ((fleet_name, "newcomer"), (flood_fleet, "late")):

            def served(fleet: str = fleet, robot: str = robot) -> bool:
                state = client.state(robot, fleet=fleet, timeout_s=2.0)
                return state is not None and state.frames_applied == len(frames)

            wait_until(served, 60.0, f"{fleet}/{robot} served")
            state = client.state(robot, fleet=fleet, timeout_s=2.0)
            assert state is not None
            assert (state.frames_missing, state.frames_rejected) == (0, 0)
    assert errors.of("newcomer") == []
    assert flood_errors.of("late") == []
    limit = [e for e in list(flood_errors.items) if e.code.value == "SESSION_LIMIT"]
    assert limit, "the flood was never refused"
    assert all("new sessions a second" in e.detail or "shard limit" in e.detail for e in limit)
    assert metric_value(service.metrics(), "lessmap_sessions_evicted_total") > 0
    errors.close()
    flood_errors.close()
    assert service.terminate() == 0

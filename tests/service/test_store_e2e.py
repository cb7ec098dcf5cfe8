"""The state store seen from outside: a damaged store file, a robot pausing past the timeout.

Real ``lessmap serve`` processes on loopback; the state directory is the test's own
(``$XDG_STATE_HOME/lessmap``, set per test by the autouse fixture in ``tests/conftest.py``).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import pytest

from lessmap.files.frames import read_frames
from lessmap.runtime.store import STORE_FILE
from lessmap_client import FleetClient, RobotPublisher
from tests.conftest import ServeProcess, dataset, metric_value, wait_until
from tests.service.test_serve_e2e import as_record, drain, offline_transitions, wait_closed

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import zenoh

pytestmark = pytest.mark.timeout(240)


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_a_damaged_store_is_reported_once_and_the_service_serves(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    private_state_dir: Path,
    fleet_name: str,
    damage: str,
) -> None:
    folder = private_state_dir / "lessmap"
    if damage == "truncated":
        # A real store with sessions in it, cut to a third (a disk that filled up, a copy
        # that stopped half-way).
        first = serve()
        session = client_session(first.endpoint)
        with RobotPublisher(fleet_name, "r", session=session) as robot:
            assert robot.wait_for_service(20.0), first.log()
            for seq in range(300):
                robot.publish([seq % 7, seq % 7 + 1, 100 + seq])
        assert first.terminate() == 0
        data = (folder / STORE_FILE).read_bytes()
        assert len(data) > 8192
        (folder / STORE_FILE).write_bytes(data[: len(data) // 3])
    else:
        folder.mkdir(parents=True)
        (folder / STORE_FILE).write_bytes(b"not a database, not at all " * 1000)

    service = serve(metrics=True)
    session = client_session(service.endpoint)
    with RobotPublisher(fleet_name, "after", session=session) as robot:
        assert robot.wait_for_service(20.0), service.log()
        for seq in range(20):
            robot.publish([1, 2, 3 + seq])
    wait_until(
        lambda: metric_value(service.metrics(), "lessmap_frames_applied_total") == 20,
        30.0,
        "the new robot's frames applied",
    )
    unreadable = [line for line in service.log().splitlines() if "is unreadable" in line]
    assert len(unreadable) == 1, service.log()
    assert list(folder.glob(f"{STORE_FILE}.corrupt-*"))  # kept aside for a post-mortem
    assert service.process.poll() is None
    assert service.terminate() == 0


def test_a_pause_longer_than_the_idle_timeout_changes_nothing(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))[:1200]
    expected = offline_transitions(frames)["0"]
    service = serve(
        "--max-batch-frames", "1", "--idle-timeout", "1", "--method", "paper", metrics=True
    )
    session = client_session(service.endpoint)
    with FleetClient(fleet_name, session=session) as client:
        with RobotPublisher(fleet_name, "dlr", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            for frame in frames[:600]:
                robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
            wait_until(
                lambda: metric_value(service.metrics(), "lessmap_sessions_evicted_total") >= 1,
                30.0,
                "the paused session evicted",
            )
            time.sleep(1.0)
            for frame in frames[600:]:
                robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
            assert robot.status.count("SESSION_CLOSED") == 0
        state = wait_closed(client, fleet_name, "dlr", len(frames))
        got = drain(client)
    assert metric_value(service.metrics(), "lessmap_sessions_resumed_total") >= 1
    assert state.frames_missing == state.frames_rejected == 0
    assert [as_record(t) for t in got] == expected
    assert service.terminate() == 0


def test_a_second_instance_on_the_same_state_directory_is_a_one_line_error(
    serve: Callable[..., ServeProcess],
) -> None:
    first = serve()
    wait_until(lambda: "serving as" in first.log(), 30.0, "the first service")
    second = serve("-m", "client", "-e", first.endpoint)  # same (test) state directory
    assert second.process.wait(60) == 1
    lines = second.log().strip().splitlines()
    assert lines[-1].startswith("lessmap serve: state directory ")
    assert lines[-1].endswith("give each instance its own --state-dir")
    assert "Traceback" not in second.log()
    assert first.terminate() == 0

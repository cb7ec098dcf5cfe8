"""A restart loses nothing: SIGTERM mid-stream, a new process on the same state directory.

Real processes on loopback: a Zenoh router opened by the test, two ``lessmap serve``
processes one after the other (peers of that router, sharing the test's state directory),
one robot replaying DLR, one fleet app. The reference is ``lessmap segment`` of the file.
"""

from __future__ import annotations

import json
import signal
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap.frames_file import read_frames
from lessmap_client import FleetClient, RobotPublisher
from tests.conftest import ServeProcess, dataset, free_port, wait_until
from tests.service.test_serve_e2e import as_record, drain, offline_transitions, wait_closed

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

pytestmark = pytest.mark.timeout(300)


@pytest.fixture
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    with zenoh.open(conf):
        yield endpoint


def test_sigterm_and_restart_resume_every_session_exactly(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    expected = offline_transitions(frames)["0"]
    half = len(frames) // 2
    options = ("-m", "peer", "-e", router, "--max-batch-frames", "1")
    session = client_session(router)
    with FleetClient(fleet_name, session=session) as client:
        robot = RobotPublisher(fleet_name, "dlr", session=session)
        first = serve(*options)
        assert robot.wait_for_service(20.0), first.log()
        for frame in frames[:half]:
            robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)

        def applied(count: int) -> Callable[[], bool]:
            def check() -> bool:
                state = client.state("dlr", fleet=fleet_name, timeout_s=2.0)
                return state is not None and state.frames_applied == count

            return check

        wait_until(applied(half), 60.0, "the first half applied")
        first.process.send_signal(signal.SIGTERM)
        assert first.process.wait(15) == 0, first.log()
        assert "session checkpoints in" in first.log()

        second = serve(*options)
        assert robot.wait_for_service(20.0), second.log()
        wait_until(lambda: "serving as" in second.log(), 20.0, "the second instance")
        for frame in frames[half:]:
            robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
        robot.close()
        state = wait_closed(client, fleet_name, "dlr", len(frames))
        got = drain(client)
        assert "session resumed from the state store" in second.log()

    assert state.frames_missing == state.frames_duplicate == state.frames_rejected == 0
    assert state.transitions == len(expected)
    # Submap ids continue across the restart, so no new event looks like an old one.
    closed_ids = [t.closed.id for t in got]
    assert closed_ids == sorted(set(closed_ids))
    assert [as_record(t) for t in got] == expected
    assert {t.instance for t in got} == {first.instance, second.instance}
    assert second.terminate() == 0

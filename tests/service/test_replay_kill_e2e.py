"""kill -9 of ``lessmap serve`` in the middle of ``lessmap replay``: nothing lost, replay exits 0.

Real processes on loopback: a Zenoh router opened by the test, ``lessmap replay`` of DLR at
speed 40 as a subprocess, a first ``lessmap serve`` killed with SIGKILL about a third of the
way in, a second one started 2 s later on the same state directory (the test's
XDG_STATE_HOME), and a fleet app. The reference is ``lessmap segment`` of the file.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap.files.frames import read_frames
from lessmap_client import FleetClient, wait_for_service
from tests.conftest import ServeProcess, dataset, wait_until
from tests.service.test_serve_e2e import as_record, drain, offline_transitions

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

pytestmark = [pytest.mark.timeout(400), pytest.mark.slow]


def test_kill_9_during_replay_loses_nothing_and_replay_exits_zero(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
    tmp_path: Path,
) -> None:
    path = dataset("dlr.frames.jsonl")
    frames = list(read_frames(path))
    expected = offline_transitions(frames)["0"]
    options = ("-m", "peer", "-e", router, "--max-batch-frames", "1", "--method", "paper")
    session = client_session(router)
    with FleetClient(fleet_name, session=session) as client:
        first = serve(*options)
        assert wait_for_service(session, 20.0), first.log()
        out = tmp_path / "replay.out"
        err = tmp_path / "replay.err"
        with out.open("wb") as stdout, err.open("wb") as stderr:
            replay = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "lessmap",
                    "replay",
                    str(path),
                    "--fleet",
                    fleet_name,
                    "--speed",
                    "40",
                    "-e",
                    router,
                    "--settle",
                    "5",
                ],
                stdout=stdout,
                stderr=stderr,
            )
        try:

            def applied_at_least(count: int) -> bool:
                state = client.state("0", fleet=fleet_name, timeout_s=2.0)
                return state is not None and state.frames_applied >= count

            wait_until(lambda: applied_at_least(1000), 90.0, "a third of DLR applied")
            first.process.send_signal(signal.SIGKILL)
            first.process.wait(10)
            time.sleep(2.0)  # the robot keeps publishing into its cache meanwhile
            second = serve(*options)
            code = replay.wait(240)
        finally:
            if replay.poll() is None:
                replay.kill()
                replay.wait(10)
        summary_lines = out.read_text(encoding="utf-8").strip().splitlines()
        assert code == 0, (err.read_text(encoding="utf-8")[-2000:], second.log()[-3000:])
        got = drain(client)

    summary = json.loads(summary_lines[-1])
    assert summary["per_robot"]["0"]["offered"] == len(frames), summary
    assert summary["per_robot"]["0"]["applied"] == len(frames), summary
    assert "session resumed from the state store" in second.log()
    assert "recovered from the robot's cache" in second.log()  # the catch-up did happen
    # FleetClient keeps the first copy of each (session, closed id): the transitions the dead
    # process published after its last checkpoint come again, identical, and are dropped.
    assert [as_record(t) for t in got] == expected
    assert second.terminate() == 0

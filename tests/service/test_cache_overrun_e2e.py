"""A kill -9 whose downtime outlasts the robot's cache: frames lost, but no identity reused.

Real processes on loopback, as in ``test_store_faults_e2e.py``: DLR replayed at speed 40 (the
robot caches 1000 frames, 25 s), ``lessmap serve`` killed with SIGKILL, and a second one
started 30 s later on the same state directory. The frames between the last checkpoint and
the oldest one the cache still holds are gone: the second service starts a new incarnation
there, and the transitions on the bus say so without contradicting the first service's.
"""

from __future__ import annotations

import signal
import time
from typing import TYPE_CHECKING

import pytest

from lessmap.files.frames import read_frames
from lessmap_client import FleetClient, wait_for_service
from tests.conftest import dataset, wait_until
from tests.service.identities import TransitionLedger
from tests.service.test_store_faults_e2e import Processes, replay_args, serve_args

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    import zenoh

pytestmark = [pytest.mark.timeout(420), pytest.mark.slow]

KILL_AT = 800
DOWNTIME_S = 30.0  # 1200 frames at speed 40: more than the robot's cache


@pytest.fixture
def processes(tmp_path: Path) -> Iterator[Processes]:
    procs = Processes(tmp_path)
    yield procs
    procs.stop_all()


def test_a_downtime_past_the_cache_starts_a_new_incarnation_without_conflicts(
    processes: Processes,
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
    tmp_path: Path,
) -> None:
    path = dataset("dlr.frames.jsonl")
    frames = list(read_frames(path))
    session = client_session(router)
    state_dir = tmp_path / "state"
    ledger = TransitionLedger(session, fleet_name)
    try:
        with FleetClient(fleet_name, session=session) as client:
            first, first_log = processes.start(serve_args(router, state_dir), "first")
            assert wait_for_service(session, 20.0), first_log.read_text()
            replay, _replay_log = processes.start(replay_args(path, fleet_name, router), "replay")

            def applied_at_least(count: int) -> bool:
                state = client.state("0", fleet=fleet_name, timeout_s=2.0)
                return state is not None and state.frames_applied >= count

            wait_until(lambda: applied_at_least(KILL_AT), 90.0, "the replay to get going")
            first.send_signal(signal.SIGKILL)
            first.wait(10)
            time.sleep(DOWNTIME_S)
            processes.start(serve_args(router, state_dir), "second")
            replay.wait(240)
            time.sleep(1.0)  # the last transitions on their way
            state = client.state("0", fleet=fleet_name, timeout_s=5.0)
    finally:
        ledger.close()
    assert state is not None
    assert state.frames_missing > 0  # the cache did not reach back: history was lost
    assert state.frames_applied + state.frames_missing + state.frames_rejected == len(frames)
    assert ledger.conflicts() == [], "identities published with different content"
    incarnations = sorted({t.incarnation for t in ledger.transitions})
    assert incarnations[0] == 0
    assert len(incarnations) == 2, incarnations  # the loss shows in the transitions
    assert incarnations[1] == state.incarnation > KILL_AT

"""Two ``serve --memory-only`` instances: a session moved between them goes on where it was.

Real processes on loopback. Robots stream MRCLAM 6 to instance A alone; then instance B
joins (as a ``serve --workers 2`` worker does, or a restarted worker), and A hands B's
partitions over with their sessions. Without a state file the records travel on A's shelf
(``runtime/shelf.py``); the robots' transitions must equal ``lessmap segment``'s and no
robot may see a ``SEQ_GAP``. B's process is stopped by its PID.
"""

from __future__ import annotations

import contextlib
import dataclasses
import re
import subprocess
import sys
import time
from typing import TYPE_CHECKING

import pytest

from lessmap.files.frames import read_frames
from lessmap_client import FleetClient, RobotPublisher
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.partition import assignment, partition_of
from tests.conftest import ServeProcess, dataset, wait_until
from tests.service.test_serve_e2e import as_record, drain, offline_transitions

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import zenoh

    from lessmap_schemas.messages import Error

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]

FRAMES_EACH = 600
BEFORE_THE_MOVE = 150  # frames each robot sends to A before B joins
OPTIONS = ("--memory-only", "--workers", "1", "--max-batch-frames", "1", "--method", "paper")
HANDED = re.compile(r"handed over \d+ partition\(s\) \((\d+) session\(s\) checkpointed\)")
TOOK = re.compile(r"took \d+ partition\(s\) in \d+ ms \((\d+) checkpoint\(s\) from other")


def names_on_both(first: str, second: str, fleet: str, count: int) -> list[str]:
    """``count`` robot names, at least two in ``second``'s partitions and one in ``first``'s."""
    table = assignment([first, second])
    names = [f"r{i}" for i in range(500)]
    on_second = [n for n in names if table[partition_of(fleet, n)][0] == second]
    on_first = [n for n in names if n not in on_second]
    return sorted([*on_second[:2], *on_first[: count - 2]])


def start_second(endpoint: str, instance: str, log: Path) -> ServeProcess:
    """A second instance, a Zenoh client of the first's router."""
    args = [sys.executable, "-m", "lessmap", "-v", "serve", "-m", "client", "-e", endpoint]
    args += ["--cfg", "scouting/multicast/enabled:false", "--instance", instance, *OPTIONS]
    with log.open("wb") as out:
        process = subprocess.Popen(args, stdout=out, stderr=out)
    return ServeProcess(endpoint, process, log, instance)


def test_memory_only_instances_move_sessions_without_restarting_them(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    tmp_path: Path,
) -> None:
    source = [f for f in read_frames(dataset("mrclam6.frames.jsonl")) if f.seq < FRAMES_EACH]
    streams = sorted({f.robot for f in source})
    first = serve(*OPTIONS)
    second_name = f"{first.instance}-b"
    names = names_on_both(first.instance, second_name, fleet_name, len(streams))
    robots = dict(zip(streams, names, strict=True))
    frames = [dataclasses.replace(f, robot=robots[f.robot]) for f in source]
    expected = offline_transitions(frames)
    by_robot = {r: [f for f in frames if f.robot == r] for r in robots.values()}
    wait_until(lambda: f"serving as {first.instance}" in first.log(), 60.0, "A", first.log)
    session = client_session(first.endpoint)
    errors: list[Error] = []
    started: list[ServeProcess] = []  # B, stopped by its PID whatever happens
    try:
        with FleetClient(fleet_name, session=session) as client:
            publishers = {
                r: RobotPublisher(fleet_name, r, session=session, on_error=errors.append)
                for r in by_robot
            }

            def publish(indices: range) -> None:
                for index in indices:
                    for robot, publisher in publishers.items():
                        frame = by_robot[robot][index]
                        publisher.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
                    time.sleep(0.005)

            try:
                for publisher in publishers.values():
                    assert publisher.wait_for_service(30.0)
                publish(range(BEFORE_THE_MOVE))
                second = start_second(first.endpoint, second_name, tmp_path / "b.log")
                started.append(second)
                wait_until(lambda: TOOK.search(second.log()) is not None, 90.0, "B", second.log)
                publish(range(BEFORE_THE_MOVE, FRAMES_EACH))
            finally:
                for publisher in publishers.values():
                    publisher.close()
            got = drain(client, quiet_s=2.0)
    finally:
        for proc in started:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.terminate(timeout_s=20.0)  # killed by PID after the timeout
    handed = [int(n) for n in HANDED.findall(first.log())]
    fetched = [int(n) for n in TOOK.findall(second.log())]
    assert max(handed) >= 2, first.log()[-3000:]  # the sessions on B's partitions moved
    assert max(fetched) >= 2, second.log()[-3000:]  # and B fetched their records
    assert [e for e in errors if e.code == ErrorCode.SEQ_GAP] == []
    received: dict[str, list[dict[str, object]]] = {}
    for t in got:
        received.setdefault(t.robot, []).append(as_record(t))
    assert received == {r: ts for r, ts in expected.items() if ts}
    assert first.terminate() == 0

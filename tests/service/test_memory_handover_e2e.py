"""``serve --memory-only --workers 2``: a session moved between workers goes on where it was.

Real processes on loopback. Robots stream MRCLAM 6 while worker 1 is still starting, so
worker 0 opens every session and then hands worker 1's partitions over to it. Without a
state file the records travel on worker 0's shelf (``runtime/shelf.py``); the robots'
transitions must equal ``lessmap segment``'s and no robot may see a ``SEQ_GAP``.
"""

from __future__ import annotations

import dataclasses
import re
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

    import zenoh

    from lessmap_schemas.messages import Error

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]

FRAMES_EACH = 600
BEFORE_THE_MOVE = 150  # frames each robot sends before worker 1 takes its partitions
HANDED = re.compile(r"handed over \d+ partition\(s\) \((\d+) session\(s\) checkpointed\)")
TOOK = re.compile(r"took \d+ partition\(s\) in \d+ ms \((\d+) checkpoint\(s\) from other")


def names_on_both(instance: str, fleet: str, count: int) -> list[str]:
    """``count`` robot names, at least two in worker 1's partitions and one in worker 0's."""
    table = assignment([f"{instance}-w0", f"{instance}-w1"])
    names = [f"r{i}" for i in range(500)]
    on_w1 = [n for n in names if table[partition_of(fleet, n)][0] == f"{instance}-w1"]
    on_w0 = [n for n in names if n not in on_w1]
    return sorted([*on_w1[:2], *on_w0[: count - 2]])


def test_memory_only_workers_move_sessions_without_restarting_them(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    source = [f for f in read_frames(dataset("mrclam6.frames.jsonl")) if f.seq < FRAMES_EACH]
    streams = sorted({f.robot for f in source})
    service = serve(
        "--memory-only", "--workers", "2", "--max-batch-frames", "1", "--method", "paper"
    )
    robots = dict(
        zip(streams, names_on_both(service.instance, fleet_name, len(streams)), strict=True)
    )
    frames = [dataclasses.replace(f, robot=robots[f.robot]) for f in source]
    expected = offline_transitions(frames)
    by_robot = {r: [f for f in frames if f.robot == r] for r in robots.values()}
    wait_until(
        lambda: f"serving as {service.instance}-w0" in service.log(), 90.0, "w0", service.log
    )
    session = client_session(service.endpoint)
    errors: list[Error] = []
    with FleetClient(fleet_name, session=session) as client:
        publishers = {
            r: RobotPublisher(fleet_name, r, session=session, on_error=errors.append)
            for r in by_robot
        }
        try:
            for publisher in publishers.values():
                assert publisher.wait_for_service(30.0)
            for index in range(FRAMES_EACH):
                if index == BEFORE_THE_MOVE:
                    wait_until(
                        lambda: TOOK.search(service.log()) is not None,
                        90.0,
                        "w1 taking over",
                        service.log,
                    )
                for robot, publisher in publishers.items():
                    frame = by_robot[robot][index]
                    publisher.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
                time.sleep(0.005)
        finally:
            for publisher in publishers.values():
                publisher.close()
        got = drain(client, quiet_s=2.0)
    log = service.log()
    assert max(int(n) for n in HANDED.findall(log)) >= 2, log[-3000:]  # sessions did move
    assert max(int(n) for n in TOOK.findall(log)) >= 2, log[-3000:]  # and were fetched
    assert [e for e in errors if e.code == ErrorCode.SEQ_GAP] == []
    received: dict[str, list[dict[str, object]]] = {}
    for t in got:
        received.setdefault(t.robot, []).append(as_record(t))
    assert received == {r: ts for r, ts in expected.items() if ts}
    assert service.terminate() == 0

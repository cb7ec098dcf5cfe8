"""``lessmap serve --workers 2``: one command, two instance processes, one stop.

Real processes on loopback: the parent hosts the router on the test's endpoint, its
workers are clients of it. ``lessmap replay`` of MRCLAM 6 (five robots, so both workers
hold some) is compared with ``lessmap segment`` of the file; a worker is killed with
SIGKILL in the middle of a replay; the parent is stopped with SIGTERM and killed with
SIGKILL. Every process is found and checked by its PID.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap.files.frames import read_frames
from lessmap_client import FleetClient
from lessmap_schemas.partition import assignment, partition_of
from tests.conftest import ServeProcess, dataset, wait_until
from tests.service.test_serve_e2e import as_record, drain, offline_transitions

if TYPE_CHECKING:
    from collections.abc import Callable

pytestmark = [pytest.mark.timeout(400), pytest.mark.slow]

OPTIONS = ("--workers", "2", "--max-batch-frames", "1", "--method", "paper")


def alive(pid: int) -> bool:
    """Whether a process runs (a zombie waiting for its parent's reaping counts as ended)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[0] not in {"Z", "X"}


def workers_of(parent: int) -> dict[str, int]:
    """The parent's worker processes, by worker tag (``w0``), from /proc."""
    found: dict[str, int] = {}
    try:
        children = Path(f"/proc/{parent}/task/{parent}/children").read_text().split()
    except OSError:
        return found
    for pid in map(int, children):
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        for arg in argv:
            if arg.endswith(b".json") and b"lessmap-workers-" in arg:
                found[Path(arg.decode()).stem] = pid
    return found


def start_workers(serve: Callable[..., ServeProcess]) -> ServeProcess:
    """``serve --workers 2``, returned once both workers serve (their partitions taken)."""
    service = serve(*OPTIONS)
    wait_until(
        lambda: f"serving as {service.instance}-w1" in service.log(),
        90.0,
        "both workers to serve",
        service.log,
    )
    return service


def replay(endpoint: str, path: Path, fleet: str, out: Path) -> subprocess.Popen[bytes]:
    args = [sys.executable, "-m", "lessmap", "replay", str(path), "--fleet", fleet]
    args += ["--speed", "40", "-e", endpoint, "--settle", "5"]
    with out.open("wb") as stdout, out.with_suffix(".err").open("wb") as stderr:
        return subprocess.Popen(args, stdout=stdout, stderr=stderr)


def finish(process: subprocess.Popen[bytes], out: Path) -> dict[str, object]:
    """Wait for ``lessmap replay``; its JSON summary (the test fails on a non-zero exit)."""
    try:
        code = process.wait(240)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(10)
    err = out.with_suffix(".err").read_text(encoding="utf-8")
    assert code == 0, err[-2000:]
    summary: dict[str, object] = json.loads(out.read_text(encoding="utf-8").splitlines()[-1])
    return summary


def test_two_workers_serve_a_replay_as_segment_does(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    tmp_path: Path,
) -> None:
    path = dataset("mrclam6.frames.jsonl")
    frames = list(read_frames(path))
    expected = offline_transitions(frames)
    service = start_workers(serve)
    names = [f"{service.instance}-w0", f"{service.instance}-w1"]
    with FleetClient(fleet_name, session=client_session(service.endpoint)) as client:
        summary = finish(
            replay(service.endpoint, path, fleet_name, tmp_path / "r.out"), tmp_path / "r.out"
        )
        got = drain(client)
    per_robot = summary["per_robot"]
    assert isinstance(per_robot, dict)
    assert all(r["applied"] == r["offered"] for r in per_robot.values()), summary
    by_robot: dict[str, list[dict[str, object]]] = {}
    for t in got:
        by_robot.setdefault(t.robot, []).append(as_record(t))
    assert by_robot == {r: ts for r, ts in expected.items() if ts}
    table = assignment(names)
    owners = {table[partition_of(fleet_name, r)][0] for r, ts in expected.items() if ts}
    assert {t.instance for t in got} == owners  # each robot decided by its partition's owner
    log = service.log()
    assert " w0 lessmap." in log  # every worker's lines name it
    assert " w1 lessmap." in log
    assert service.terminate() == 0


def test_kill_9_of_a_worker_loses_nothing_and_it_is_restarted(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    tmp_path: Path,
) -> None:
    path = dataset("mrclam6.frames.jsonl")
    frames = list(read_frames(path))
    expected = offline_transitions(frames)
    busiest = max(expected, key=lambda r: sum(f.robot == r for f in frames))
    service = start_workers(serve)
    names = [f"{service.instance}-w0", f"{service.instance}-w1"]
    owner = assignment(names)[partition_of(fleet_name, busiest)][0]
    assert owner is not None
    tag = owner.rsplit("-", 1)[1]
    session = client_session(service.endpoint)
    with FleetClient(fleet_name, session=session) as client:
        out = tmp_path / "r.out"
        running = replay(service.endpoint, path, fleet_name, out)

        def applied_at_least(count: int) -> bool:
            state = client.state(busiest, fleet=fleet_name, timeout_s=2.0)
            return state is not None and state.frames_applied >= count

        wait_until(lambda: applied_at_least(700), 120.0, f"700 frames of robot {busiest}")
        victim = workers_of(service.process.pid)[tag]
        os.kill(victim, signal.SIGKILL)
        summary = finish(running, out)
        got = drain(client)
    per_robot = summary["per_robot"]
    assert isinstance(per_robot, dict)
    assert all(r["applied"] == r["offered"] for r in per_robot.values()), summary
    by_robot: dict[str, list[dict[str, object]]] = {}
    for t in got:  # FleetClient keeps the first copy of each transition
        by_robot.setdefault(t.robot, []).append(as_record(t))
    assert by_robot == {r: ts for r, ts in expected.items() if ts}
    log = service.log()
    assert f"worker {tag} (pid {victim}) was killed by SIGKILL" in log
    serves = f"worker {tag} (pid "  # "worker w1 (pid N) serves", after the kill's line
    wait_until(
        lambda: serves in service.log().rsplit("was killed by SIGKILL", 1)[1],
        60.0,
        f"{tag} serving again",
        service.log,
    )
    assert workers_of(service.process.pid)[tag] != victim
    assert not alive(victim)
    assert service.terminate() == 0


def test_one_stop_ends_every_worker(serve: Callable[..., ServeProcess]) -> None:
    service = start_workers(serve)
    pids = workers_of(service.process.pid)
    assert sorted(pids) == ["w0", "w1"]
    assert service.terminate(timeout_s=60.0) == 0
    assert not any(alive(pid) for pid in pids.values())


def test_kill_9_of_the_parent_ends_every_worker(serve: Callable[..., ServeProcess]) -> None:
    service = start_workers(serve)
    pids = workers_of(service.process.pid)
    assert sorted(pids) == ["w0", "w1"]
    service.process.send_signal(signal.SIGKILL)
    service.process.wait(10)
    wait_until(
        lambda: not any(alive(pid) for pid in pids.values()),
        30.0,
        "the workers to end with their parent",
        service.log,
    )
    assert "received SIGTERM" in service.log()  # each stopped cleanly, not killed

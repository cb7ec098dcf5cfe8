"""The state store fails mid-replay, heals, then ``lessmap serve`` dies by kill -9: nothing lost.

Real processes on loopback: a Zenoh router opened by the test, ``lessmap replay`` of DLR at
speed 40 (its robot keeps 1000 frames in its publication cache), and a ``lessmap serve``
whose store fails a sixth of the way in: its filesystem fills up (freed later), or its files
are deleted, or overwritten with garbage. Once the store is back the service is killed with
SIGKILL and a second one starts on the same state directory. The frames since the fault
outnumber the robot's cache, so only a healed store lets the second service resume.

Judged on the bus: every robot frame applied, the transitions equal to ``lessmap segment``
offline, and no identity published twice with different content.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.files.frames import read_frames
from lessmap.runtime.store import STORE_FILE
from lessmap_client import FleetClient, wait_for_service
from tests.conftest import dataset, wait_until
from tests.service.identities import TransitionLedger
from tests.service.test_serve_e2e import as_record, offline_transitions

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    import zenoh

pytestmark = [pytest.mark.timeout(420), pytest.mark.slow]

FAULT_AT = 600  # frames applied when the store fails (speed 40: 15 s in)
HEAL_AT = 1100  # when a full disk gets space back
KILL_AT = 2100  # more than the robot's cache (1000 frames) after the fault
TMPFS_BYTES = 32 << 20


class Processes:
    """Processes a test starts; each is stopped by its PID at teardown."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.started: list[subprocess.Popen[bytes]] = []

    def start(self, args: list[str], name: str) -> tuple[subprocess.Popen[bytes], Path]:
        log_path = self.folder / f"{name}.log"
        with log_path.open("wb") as log_file:
            process = subprocess.Popen(args, stdout=log_file, stderr=log_file)
        self.started.append(process)
        return process, log_path

    def stop_all(self) -> None:
        for process in reversed(self.started):
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
                try:
                    process.wait(10)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait(5)


@pytest.fixture
def processes(tmp_path: Path) -> Iterator[Processes]:
    procs = Processes(tmp_path)
    yield procs
    procs.stop_all()


class SmallDisk:
    """A size-limited tmpfs in a user and mount namespace of its own, held by a sleeper.

    Services run inside it (``nsenter``); the test reaches its files from outside through
    ``/proc/<holder>/root``.
    """

    def __init__(self, processes: Processes, mount_point: Path) -> None:
        if shutil.which("unshare") is None or shutil.which("nsenter") is None:
            pytest.skip("unshare/nsenter not installed: no private tmpfs")
        mount_point.mkdir()
        script = (
            f"mount -t tmpfs -o size={TMPFS_BYTES} tmpfs {mount_point} && "
            f"touch {mount_point}/ready && exec sleep 600"
        )
        self.holder, _log = processes.start(["unshare", "-rm", "sh", "-c", script], "holder")
        self.mount_point = mount_point
        self.outside = Path(f"/proc/{self.holder.pid}/root{mount_point}")
        deadline = time.monotonic() + 10.0
        while not (self.holder.poll() is None and (self.outside / "ready").exists()):
            if self.holder.poll() is not None or time.monotonic() > deadline:
                pytest.skip("user namespaces unavailable here: cannot mount a private tmpfs")
            time.sleep(0.05)

    def prefix(self) -> list[str]:
        return ["nsenter", "-t", str(self.holder.pid), "-U", "-m", "--preserve-credentials"]

    def fill(self) -> None:
        """Write a filler file until the filesystem is full."""
        # Unbuffered: nothing is left to flush at the close once the disk is full (ENOSPC).
        with (
            (self.outside / "filler").open("wb", buffering=0) as filler,
            contextlib.suppress(OSError),
        ):
            while True:
                filler.write(b"\0" * 65536)

    def free(self) -> None:
        (self.outside / "filler").unlink()


def last_summary(replay_log: Path) -> dict[str, Any]:
    """The JSON summary ``lessmap replay`` prints last on stdout (its log shares the file)."""
    lines = replay_log.read_text(errors="replace").splitlines()
    summary: dict[str, Any] = json.loads(next(x for x in reversed(lines) if x.startswith("{")))
    return summary


def serve_args(router: str, state_dir: Path) -> list[str]:
    return [
        sys.executable,
        "-m",
        "lessmap",
        "-v",
        "serve",
        "-m",
        "peer",
        "-e",
        router,
        "--cfg",
        "scouting/multicast/enabled:false",
        "--instance",
        f"test-{uuid.uuid4().hex[:8]}",
        "--state-dir",
        str(state_dir),
        "--max-batch-frames",
        "1",
        "--method",
        "paper",
    ]


def replay_args(path: Path, fleet: str, router: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "lessmap",
        "replay",
        str(path),
        "--fleet",
        fleet,
        "--speed",
        "40",
        "-e",
        router,
        "--settle",
        "5",
    ]


def run_with_fault(
    *,
    processes: Processes,
    session: zenoh.Session,
    router: str,
    fleet: str,
    state_dir: Path,
    prefix: list[str],
    inject: Callable[[], None],
    heal: Callable[[], None],
) -> None:
    """The scenario of the module docstring; asserts what it promises."""
    path = dataset("dlr.frames.jsonl")
    frames = list(read_frames(path))
    expected = offline_transitions(frames)["0"]
    ledger = TransitionLedger(session, fleet)
    try:
        with FleetClient(fleet, session=session) as client:
            first, first_log = processes.start(prefix + serve_args(router, state_dir), "first")
            assert wait_for_service(session, 20.0), first_log.read_text()
            replay, replay_log = processes.start(replay_args(path, fleet, router), "replay")

            def applied_at_least(count: int) -> bool:
                state = client.state("0", fleet=fleet, timeout_s=2.0)
                return state is not None and state.frames_applied >= count

            def logged(text: str) -> bool:
                # Bounded, and not an assertion yet: the frames lost are the first verdict.
                deadline = time.monotonic() + 15.0
                while text not in first_log.read_text(errors="replace"):
                    if time.monotonic() > deadline:
                        return False
                    time.sleep(0.1)
                return True

            wait_until(lambda: applied_at_least(FAULT_AT), 90.0, "the replay to get going")
            inject()
            lost_reported = logged("durability lost")
            wait_until(lambda: applied_at_least(HEAL_AT), 90.0, "the replay to go on")
            heal()
            back_reported = logged("durability back")
            wait_until(lambda: applied_at_least(KILL_AT), 90.0, "the replay to go on")
            first.send_signal(signal.SIGKILL)
            first.wait(10)
            time.sleep(2.0)  # the robot keeps publishing into its cache meanwhile
            _second, second_log = processes.start(prefix + serve_args(router, state_dir), "second")
            code = replay.wait(240)
            summary = last_summary(replay_log)
            time.sleep(1.0)  # the last transitions on their way
    finally:
        ledger.close()
    robot = summary["per_robot"]["0"]
    lost = len(frames) - robot["applied"]
    conflicts = ledger.conflicts()
    assert (lost, len(conflicts)) == (0, 0), (
        f"{lost} frames lost, {len(conflicts)} conflicting identities",
        summary,
        second_log.read_text()[-3000:],
    )
    assert code == 0, replay_log.read_text()[-2000:]
    assert [as_record(t) for t in ledger.distinct()] == expected
    assert lost_reported, "no 'durability lost' in the log"
    assert back_reported, "no 'durability back' in the log"


def test_disk_full_then_freed_mid_replay_loses_nothing(
    processes: Processes,
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
    tmp_path: Path,
) -> None:
    disk = SmallDisk(processes, tmp_path / "small")
    run_with_fault(
        processes=processes,
        session=client_session(router),
        router=router,
        fleet=fleet_name,
        state_dir=disk.mount_point / "state",
        prefix=disk.prefix(),
        inject=disk.fill,
        heal=disk.free,
    )


def test_store_deleted_mid_replay_loses_nothing(
    processes: Processes,
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
    tmp_path: Path,
) -> None:
    state_dir = tmp_path / "state"

    def delete() -> None:
        for suffix in ("", "-wal", "-shm"):
            (state_dir / (STORE_FILE + suffix)).unlink(missing_ok=True)

    run_with_fault(
        processes=processes,
        session=client_session(router),
        router=router,
        fleet=fleet_name,
        state_dir=state_dir,
        prefix=[],
        inject=delete,
        heal=lambda: None,
    )


def test_store_corrupted_mid_replay_loses_nothing(
    processes: Processes,
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
    tmp_path: Path,
) -> None:
    state_dir = tmp_path / "state"

    def corrupt() -> None:
        # The database and its write-ahead log, each over its whole length: what SQLite
        # wrote cannot be read back from either.
        for suffix in ("", "-wal"):
            part = state_dir / (STORE_FILE + suffix)
            size = max(part.stat().st_size, 1 << 16)
            part.write_bytes((bytes(range(256)) * (size // 256 + 1))[:size])

    run_with_fault(
        processes=processes,
        session=client_session(router),
        router=router,
        fleet=fleet_name,
        state_dir=state_dir,
        prefix=[],
        inject=corrupt,
        heal=lambda: None,
    )

"""Durable sessions: checkpoints in the SQLite store, resume, eviction, damaged stores.

The session table and the store are real (a SQLite file under ``tmp_path``); a "restart"
is a new store and a new table on the same folder, a "crash" drops the old ones without
stopping them. The reference is one table that never stopped.
"""

from __future__ import annotations

import sqlite3
import time
from typing import TYPE_CHECKING

import pytest

from lessmap.core import PartitionParams
from lessmap.runtime.sessions import Outcome, SessionTable
from lessmap.runtime.store import STORE_FILE, CheckpointStore, SessionRecord
from lessmap.sim.simulator import simulate
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from pathlib import Path

LASER = PartitionParams.from_profile("laser")
FLEET = "fleet"
ROBOT = "robot0"
SESSION = "s1"


def walk() -> list[Frame]:
    """One simulated robot walking an 8-room building: several transitions."""
    run = simulate(3, rooms=8, robots=1, frames_per_robot=400)
    return [
        Frame(session=SESSION, seq=f["seq"], stamp_s=f["stamp"], features=f["features"])
        for f in run.frames
    ]


FRAMES = walk()


def make_table(store: CheckpointStore | None, *, every: int = 25) -> SessionTable:
    return SessionTable(
        LASER,
        max_sessions=8,
        max_nodes=20_000,
        max_batch_frames=1,
        idle_timeout_s=10.0,
        instance="test",
        clock=time.perf_counter,
        store=store,
        checkpoint_every_frames=every,
        checkpoint_interval_s=3600.0,
    )


def open_store(folder: Path) -> CheckpointStore:
    store = CheckpointStore(folder)
    store.open()
    return store


def feed(table: SessionTable, frames: list[Frame], now_s: float = 0.0) -> list[Outcome]:
    return [table.handle_batch([(FLEET, ROBOT, f)], now_s) for f in frames]


def transitions(outcomes: list[Outcome]) -> list[tuple[int, int, tuple[int, ...]]]:
    """(seq, closed submap id, closed features) of every transition."""
    return [
        (t.seq, t.closed.id, tuple(t.closed.features)) for o in outcomes for _, t in o.transitions
    ]


def errors(outcomes: list[Outcome]) -> list[ErrorCode]:
    return [r.code for o in outcomes for r in o.rejections]


REFERENCE = transitions(feed(make_table(None), FRAMES))


def test_the_walk_has_transitions_to_compare() -> None:
    assert len(REFERENCE) >= 3


def test_stop_and_restart_resume_exactly(tmp_path: Path) -> None:
    half = len(FRAMES) // 2
    store = open_store(tmp_path)
    table = make_table(store)
    first = feed(table, FRAMES[:half])
    stopped = table.close_all("shutdown")
    assert [s.open for s in stopped.suspended] == [True]
    assert not stopped.closed  # a stop is not the end of the robot's session
    store.close()

    store = open_store(tmp_path)
    table = make_table(store)
    second = feed(table, FRAMES[half:])
    assert len(second[0].resumed) == 1
    assert transitions(first) + transitions(second) == REFERENCE
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert state.frames_applied == len(FRAMES)
    assert state.frames_missing == state.frames_duplicate == 0
    store.close()


def test_crash_resumes_from_the_checkpoint_and_redelivered_frames_are_silent(
    tmp_path: Path,
) -> None:
    crash_at = 230  # frames applied by the process that dies; its last checkpoint is at 225
    store = open_store(tmp_path)
    table = make_table(store, every=25)
    before = feed(table, FRAMES[:crash_at])
    assert store.flush()
    del table, store  # kill -9: no stop, no final checkpoint

    store = open_store(tmp_path)
    table = make_table(store, every=25)
    # The robot's cache answers the catch-up with everything it still holds, from seq 0.
    after = feed(table, FRAMES)
    checkpoint_seq = 224  # 225 frames applied, seqs 0..224
    assert not errors(after)  # redeliveries up to the checkpoint are not errors
    replayed = transitions(after)
    assert replayed == [t for t in REFERENCE if t[0] > checkpoint_seq]
    # What the dead process published after its checkpoint comes again, identical, so a
    # client that de-duplicates on (session, closed id) drops exactly the repeats.
    published_before = transitions(before)
    assert [t for t in published_before if t[0] > checkpoint_seq] == [
        t for t in replayed if t[0] < crash_at
    ]
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert state.frames_applied == len(FRAMES)
    assert state.frames_duplicate == checkpoint_seq + 1
    store.close()


def test_idle_sessions_are_evicted_and_resume(tmp_path: Path) -> None:
    half = len(FRAMES) // 2
    store = open_store(tmp_path)
    table = make_table(store)
    first = feed(table, FRAMES[:half], now_s=0.0)
    expired = table.expire_idle(100.0)
    assert expired.evicted == 1
    assert not expired.closed
    assert len(table) == 0
    evicted_state = table.state(FLEET, ROBOT)  # answered from the store
    assert evicted_state is not None
    assert evicted_state.frames_applied == half
    second = feed(table, FRAMES[half:], now_s=200.0)
    assert not errors(second)
    assert transitions(first) + transitions(second) == REFERENCE
    store.close()


def test_memory_only_closes_idle_sessions_as_before() -> None:
    table = make_table(CheckpointStore(None))
    feed(table, FRAMES[:10], now_s=0.0)
    expired = table.expire_idle(100.0)
    assert expired.evicted == 0
    assert [cause for _, cause in expired.closed] == ["idle"]


def test_a_closed_session_stays_closed_across_a_restart(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = make_table(store)
    feed(table, FRAMES[:20])
    table.handle_batch([(FLEET, ROBOT, SessionEnd(session=SESSION, last_seq=19, stamp_s=99.0))], 0)
    store.close()

    store = open_store(tmp_path)
    table = make_table(store)
    out = feed(table, FRAMES[20:21])
    assert errors(out) == [ErrorCode.SESSION_CLOSED]
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert not state.open
    assert state.frames_applied == 20
    store.close()


def test_a_corrupt_store_file_is_moved_aside(tmp_path: Path) -> None:
    (tmp_path / STORE_FILE).write_bytes(b"this is not a database" * 100)
    store = open_store(tmp_path)
    assert len(store.problems) == 1
    assert "unreadable" in store.problems[0]
    assert list(tmp_path.glob(f"{STORE_FILE}.corrupt-*"))
    table = make_table(store)
    assert transitions(feed(table, FRAMES)) == REFERENCE
    store.close()


def test_a_truncated_store_file_is_moved_aside(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = make_table(store)
    feed(table, FRAMES[:100])
    table.close_all("shutdown")
    store.close()
    data = (tmp_path / STORE_FILE).read_bytes()
    (tmp_path / STORE_FILE).write_bytes(data[: len(data) // 3])
    store = open_store(tmp_path)
    table = make_table(store)
    feed(table, FRAMES[100:])  # nothing to resume from: the frames start a fresh graph
    assert len(store.problems) == 1
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert state.frames_applied == len(FRAMES) - 100
    store.close()


def test_an_unreadable_checkpoint_costs_only_its_session(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    store.save(
        SessionRecord(
            fleet=FLEET,
            robot=ROBOT,
            session=SESSION,
            status="open",
            last_seq=5,
            meta={},
            snapshot=b"garbage",
            updated_s=0.0,
        )
    )
    table = make_table(store)
    out = table.handle_batch([(FLEET, ROBOT, FRAMES[6]), (FLEET, "other", FRAMES[0])], 0.0)
    internal = [r for r in out.rejections if r.code is ErrorCode.INTERNAL]
    assert [(r.robot, "checkpoint unreadable" in r.detail) for r in internal] == [(ROBOT, True)]
    other = table.state(FLEET, "other")
    mine = table.state(FLEET, ROBOT)
    assert other is not None
    assert mine is not None
    assert other.frames_applied == 1
    assert mine.frames_applied == 1  # started fresh at the frame that found the damage
    store.close()


def test_records_survive_in_sqlite_with_wal(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = make_table(store, every=10)
    feed(table, FRAMES[:35])
    assert store.flush()
    with sqlite3.connect(tmp_path / STORE_FILE) as db:
        (mode,) = db.execute("PRAGMA journal_mode").fetchone()
        rows = db.execute("SELECT status, last_seq FROM sessions").fetchall()
    assert mode == "wal"
    assert rows == [("open", 29)]
    store.close()


def test_retention_and_size_bounds_drop_old_records(tmp_path: Path) -> None:
    clock = [1000.0]
    store = CheckpointStore(tmp_path, retention_s=50.0, clock=lambda: clock[0])
    store.open()
    for index in range(3):
        store.save(
            SessionRecord(
                fleet=FLEET,
                robot=f"r{index}",
                session=SESSION,
                status="evicted",
                last_seq=1,
                meta={},
                snapshot=b"x",
                updated_s=900.0 + 100 * index,  # 900, 1000, 1100
            )
        )
    assert store.flush()
    clock[0] = 2000.0 + 1100.0  # force a prune pass at the next write
    store.save(
        SessionRecord(
            fleet=FLEET,
            robot="fresh",
            session=SESSION,
            status="open",
            last_seq=1,
            meta={},
            snapshot=b"x",
            updated_s=clock[0],
        )
    )
    assert store.flush()
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and len(store.records()) > 1:
        time.sleep(0.02)
    assert [r.robot for r in store.records()] == ["fresh"]
    store.close()


@pytest.mark.parametrize("every", [1, 7, 1000])
def test_checkpoint_frequency_never_changes_decisions(tmp_path: Path, every: int) -> None:
    store = open_store(tmp_path)
    table = make_table(store, every=every)
    assert transitions(feed(table, FRAMES)) == REFERENCE
    store.close()

"""Durable sessions: checkpoints, resume after a stop or a crash, eviction, closed sessions."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from lessmap.runtime.store import CheckpointStore
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import SessionEnd
from tests.service.durable_helpers import (
    FLEET,
    FRAMES,
    REFERENCE,
    ROBOT,
    SESSION,
    crash,
    errors,
    feed,
    make_table,
    open_store,
    transitions,
)

if TYPE_CHECKING:
    from pathlib import Path


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
    crash(store)  # kill -9: no stop, no final checkpoint
    del table, store

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
    in_memory = table.state(FLEET, ROBOT)
    expired = table.expire_idle(100.0)
    assert expired.evicted == 1
    assert not expired.closed
    assert len(table) == 0
    evicted_state = table.state(FLEET, ROBOT)  # answered from the store
    assert evicted_state is not None
    assert evicted_state.frames_applied == half
    assert evicted_state == in_memory  # made again from the snapshot and its counters
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


def test_a_stale_open_record_never_reopens_a_session_this_table_closed(tmp_path: Path) -> None:
    # The store can hand back an older record for a moment (its writer holds the newest
    # batch between the pending map and the file); a straggler frame or a repeated end must
    # not bring the closed session back from it.
    store = open_store(tmp_path)
    table = make_table(store)
    feed(table, FRAMES[:30])  # a checkpoint at 25 frames: an open record
    assert store.flush()
    stale = store.load((FLEET, ROBOT))
    assert stale is not None
    assert stale.status == "open"
    table.handle_batch([(FLEET, ROBOT, SessionEnd(session=SESSION, last_seq=29, stamp_s=99.0))], 0)
    assert store.flush()
    store.save(stale)  # what a stale read returns: the open record of the closed session
    out = feed(table, FRAMES[30:31])
    assert errors(out) == [ErrorCode.SESSION_CLOSED]
    table.handle_batch([(FLEET, ROBOT, SessionEnd(session=SESSION, last_seq=30, stamp_s=99.0))], 0)
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert (state.open, state.frames_applied, state.frames_missing) == (False, 30, 0)
    store.close()


@pytest.mark.parametrize("phase", [False, True])
@pytest.mark.parametrize("every", [1, 7, 1000])
def test_checkpoint_frequency_never_changes_decisions(
    tmp_path: Path, every: int, phase: bool
) -> None:
    store = open_store(tmp_path)
    table = make_table(store, every=every, phase=phase)
    assert transitions(feed(table, FRAMES)) == REFERENCE
    store.close()


def test_robots_checkpoint_at_phases_of_their_own(tmp_path: Path) -> None:
    # Robots that start together must not all checkpoint in the same instant.
    store = open_store(tmp_path)
    table = make_table(store, every=100, phase=True)
    first_due: dict[str, int] = {}
    for seq in range(100):
        for robot in (f"r{i}" for i in range(8)):  # the table's session limit
            if robot in first_due:
                continue
            table.handle_batch([(FLEET, robot, FRAMES[seq])], 0.0)
            if store.flush() and any(r.robot == robot for r in store.records()):
                first_due[robot] = seq
    assert len(first_due) == 8
    assert len(set(first_due.values())) >= 6  # spread over the period, not one burst
    store.close()

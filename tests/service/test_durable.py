"""Durable sessions: checkpoints in the SQLite store, resume, eviction, damaged stores.

The session table and the store are real (a SQLite file under ``tmp_path``); a "restart"
is a new store and a new table on the same folder, a "crash" drops the old ones without
stopping them. The reference is one table that never stopped. The service saves an outcome's
checkpoints once it published the outcome; ``CommittingTable`` does the same at once.
"""

from __future__ import annotations

import sqlite3
import threading
import time
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.core import PartitionParams
from lessmap.runtime.record import SessionRecord
from lessmap.runtime.sessions import (
    CatchupPolicy,
    DurabilityPolicy,
    Identity,
    Outcome,
    Segmenting,
    SessionLimits,
    SessionTable,
    commit_checkpoints,
)
from lessmap.runtime.store import STORE_FILE, CheckpointStore
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


class CommittingTable(SessionTable):
    """A session table whose outcomes' checkpoints are saved as soon as they are returned."""

    def __init__(
        self,
        store: CheckpointStore | None,
        segmenting: Segmenting,
        limits: SessionLimits,
        **policies: Any,
    ) -> None:
        super().__init__(segmenting, limits, store=store, **policies)
        self.committed_to = store

    def _committed(self, out: Outcome) -> Outcome:
        if self.committed_to is not None:
            commit_checkpoints(out, self.committed_to)
        return out

    def handle_batch(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().handle_batch(*args, **kwargs))

    def recover(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().recover(*args, **kwargs))

    def catchup_done(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().catchup_done(*args, **kwargs))

    def release_overdue(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().release_overdue(*args, **kwargs))

    def expire_idle(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().expire_idle(*args, **kwargs))

    def close_all(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().close_all(*args, **kwargs))


def make_table(
    store: CheckpointStore | None,
    *,
    every: int = 25,
    phase: bool = False,
    catchup_max_frames: int = 0,  # 0: no catch-up (the table's default)
    catchup_wait_s: float = 2.0,
) -> SessionTable:
    # phase=False: checkpoints at exact multiples of ``every``, which the tests below pin.
    return CommittingTable(
        store,
        Segmenting(params=LASER),
        SessionLimits(max_sessions=8, max_nodes=20_000, max_batch_frames=1, idle_timeout_s=10.0),
        identity=Identity(instance="test"),
        durability=DurabilityPolicy(every_frames=every, interval_s=3600.0, phased=phase),
        catchup=CatchupPolicy(max_frames=catchup_max_frames, wait_s=catchup_wait_s),
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
        (c.transition.seq, c.transition.closed.id, tuple(c.transition.closed.features))
        for o in outcomes
        for _, c in o.transitions
    ]


def errors(outcomes: list[Outcome]) -> list[ErrorCode]:
    return [r.code for o in outcomes for r in o.rejections]


REFERENCE = transitions(feed(make_table(None), FRAMES))


def crash(store: CheckpointStore) -> None:
    """What the kernel does for a process killed with -9: its files close, its lock goes."""
    lock = store._lock_file  # the test plays the kernel
    if lock is not None:
        lock.close()


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


def test_a_record_being_written_is_what_load_returns(tmp_path: Path) -> None:
    # Between the writer taking a batch and committing it, the record is in neither the
    # pending map nor the file: load must still return it, not the file's older row.
    gate, taken = threading.Event(), threading.Event()

    class SlowStore(CheckpointStore):
        def _commit(self, batch: Any) -> None:
            taken.set()
            gate.wait(10.0)
            super()._commit(batch)

    store = SlowStore(tmp_path)
    store.open()

    def record(last_seq: int) -> SessionRecord:
        return SessionRecord(
            fleet=FLEET,
            robot=ROBOT,
            session=SESSION,
            status="open",
            last_seq=last_seq,
            meta={},
            snapshot=b"x",
            updated_s=time.time() + last_seq,
        )

    gate.set()  # the first batch goes through
    store.save(record(10))
    assert store.flush()
    gate.clear()
    taken.clear()
    store.save(record(20))
    try:
        assert taken.wait(10.0)
        loaded = store.load((FLEET, ROBOT))
        assert loaded is not None
        assert loaded.last_seq == 20
        assert [r.last_seq for r in store.records_where(lambda *_: True)] == [20]
        assert store.robots_where(lambda *_: True) == [(FLEET, ROBOT)]
    finally:
        gate.set()
    assert store.flush()
    store.close()


def test_robots_where_reads_only_thenamed_fleet_and_robot(tmp_path: Path) -> None:
    from lessmap.runtime.queries import named_fleet_and_robot

    store = open_store(tmp_path)
    for fleet, robot in [("f1", "a"), ("f1", "b"), ("f2", "a")]:
        store.save(
            SessionRecord(
                fleet=fleet,
                robot=robot,
                session=SESSION,
                status="evicted",
                last_seq=1,
                meta={},
                snapshot=b"x",
                updated_s=time.time(),
            )
        )
    assert store.flush()
    every = store.robots_where(lambda *_: True)
    assert every == [("f1", "a"), ("f1", "b"), ("f2", "a")]
    assert store.robots_where(lambda *_: True, fleet="f1") == [("f1", "a"), ("f1", "b")]
    assert store.robots_where(lambda *_: True, fleet="f1", robot="b") == [("f1", "b")]
    assert store.robots_where(lambda _f, r: r == "a", fleet="f1") == [("f1", "a")]
    store.close()
    # A query's selector names a fleet and a robot only where it holds no wildcard.
    assert named_fleet_and_robot("lessmap/v4/f1/b/state") == ("f1", "b")
    assert named_fleet_and_robot("lessmap/v4/f1/*/areas") == ("f1", None)
    assert named_fleet_and_robot("lessmap/v4/*/b/state") == (None, None)
    assert named_fleet_and_robot("lessmap/v4/**") == (None, None)


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


@pytest.mark.parametrize("phase", [False, True])
@pytest.mark.parametrize("every", [1, 7, 1000])
def test_checkpoint_frequency_never_changes_decisions(
    tmp_path: Path, every: int, phase: bool
) -> None:
    store = open_store(tmp_path)
    table = make_table(store, every=every, phase=phase)
    assert transitions(feed(table, FRAMES)) == REFERENCE
    store.close()


# -- catch-up from the robot's publication cache (sessions/catchup.py) ----------------------


def catchup_table(store: CheckpointStore | None, *, every: int = 25) -> SessionTable:
    return make_table(store, every=every, catchup_max_frames=100, catchup_wait_s=2.0)


def test_after_a_crash_the_cache_fills_the_gap_in_seq_order(tmp_path: Path) -> None:
    crash_at = 230  # applied by the process that dies; its last checkpoint is at seq 224
    store = open_store(tmp_path)
    table = catchup_table(store)
    before = feed(table, FRAMES[:crash_at])
    assert store.flush()
    crash(store)  # kill -9
    del table, store

    store = open_store(tmp_path)
    table = catchup_table(store)
    live_from = 260  # 225..259 were published while no instance ran
    first = table.handle_batch([(FLEET, ROBOT, FRAMES[live_from])], 1.0)
    assert len(first.resumed) == 1
    assert not first.transitions
    assert not errors([first])  # held, not a gap yet
    assert [(r.after_seq, r.max_frames) for r in first.catchups] == [(224, 100)]
    more = feed(table, FRAMES[live_from + 1 : live_from + 5], now_s=1.1)
    assert not any(o.catchups for o in more)  # one query per hold
    # The cache returns its newest frames, oldest first: some before the checkpoint.
    cached = FRAMES[live_from + 5 - 100 : live_from + 5]
    recovered = table.recover((FLEET, ROBOT), SESSION, cached, 1.2)
    done = table.catchup_done((FLEET, ROBOT), SESSION, 1.3)
    rest = feed(table, FRAMES[live_from + 5 :], now_s=1.4)
    assert not errors([first, *more, recovered, done, *rest])
    replayed = transitions([first, *more, recovered, done, *rest])
    assert replayed == [t for t in REFERENCE if t[0] > 224]
    assert [t for t in transitions(before) if t[0] > 224] == [
        t for t in replayed if t[0] < crash_at
    ]
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert (state.frames_applied, state.frames_missing) == (len(FRAMES), 0)
    assert state.frames_duplicate == 0  # unused cache replies are not duplicates
    store.close()


def test_only_what_no_cache_holds_is_missing(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = catchup_table(store)
    feed(table, FRAMES[:50])
    held = table.handle_batch([(FLEET, ROBOT, FRAMES[80])], 1.0)
    assert held.catchups
    # The cache lost 50..59 (too old for it): 60..79 come back.
    table.recover((FLEET, ROBOT), SESSION, FRAMES[60:80], 1.1)
    done = table.catchup_done((FLEET, ROBOT), SESSION, 1.2)
    gaps = [r for r in done.rejections if r.code is ErrorCode.SEQ_GAP]
    assert [(g.detail, g.seq) for g in gaps] == [("10 frame(s) missing: 50..59", 60)]
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert (state.frames_applied, state.frames_missing, state.last_seq) == (71, 10, 80)
    store.close()


def test_late_live_frames_fill_a_hold_without_errors(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = catchup_table(store)
    out = feed(table, FRAMES[:10])
    out.append(table.handle_batch([(FLEET, ROBOT, FRAMES[12]), (FLEET, ROBOT, FRAMES[12])], 1.0))
    out.append(table.handle_batch([(FLEET, ROBOT, FRAMES[11]), (FLEET, ROBOT, FRAMES[10])], 1.1))
    assert errors(out) == [ErrorCode.DUPLICATE_SEQ]  # the repeated 12 only
    assert table.holds == 0  # filled: applied at once, without waiting for the cache
    late = table.recover((FLEET, ROBOT), SESSION, FRAMES[:13], 1.2)  # the query's replies
    done = table.catchup_done((FLEET, ROBOT), SESSION, 1.3)
    assert not errors([late, done])
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert (state.frames_applied, state.frames_missing, state.frames_duplicate) == (13, 0, 1)
    store.close()


def end_of(last_seq: int) -> SessionEnd:
    return SessionEnd(session=SESSION, last_seq=last_seq, stamp_s=1000.0)


def test_an_end_past_the_last_frame_asks_the_cache_before_counting_the_tail_missing(
    tmp_path: Path,
) -> None:
    # A partition moved while the robot ended its session: the former owner dropped 20..29,
    # the end reached the new owner. The tail is in the robot's cache, not lost.
    store = open_store(tmp_path)
    table = catchup_table(store)
    feed(table, FRAMES[:20])
    ended = table.handle_batch([(FLEET, ROBOT, end_of(29))], 1.0)
    assert [(r.after_seq, r.max_frames) for r in ended.catchups] == [(19, 100)]
    assert not ended.closed  # the end waits for the catch-up
    assert not errors([ended])
    recovered = table.recover((FLEET, ROBOT), SESSION, FRAMES[20:30], 1.1)
    [(final, cause)] = recovered.closed
    assert cause == "ended"
    assert (final.frames_applied, final.frames_missing, final.last_seq) == (30, 0, 29)
    assert not errors([recovered])
    store.close()


def test_an_end_past_what_the_cache_holds_counts_only_the_rest_missing(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = catchup_table(store)
    feed(table, FRAMES[:20])
    ended = table.handle_batch([(FLEET, ROBOT, end_of(29))], 1.0)
    assert ended.catchups
    partial = table.recover((FLEET, ROBOT), SESSION, FRAMES[20:25], 1.1)  # 25..29 are gone
    assert not partial.closed  # more replies may come until the query is done
    done = table.catchup_done((FLEET, ROBOT), SESSION, 1.2)
    gaps = [r for r in done.rejections if r.code is ErrorCode.SEQ_GAP]
    assert [(g.detail, g.seq) for g in gaps] == [("5 frame(s) missing: 25..29", 29)]
    [(final, cause)] = done.closed
    assert cause == "ended"
    assert (final.frames_applied, final.frames_missing) == (25, 5)
    store.close()


def test_an_end_whose_catch_up_never_answers_closes_when_the_hold_expires(
    tmp_path: Path,
) -> None:
    store = open_store(tmp_path)
    table = catchup_table(store)  # catchup_wait_s=2.0
    feed(table, FRAMES[:20])
    assert table.handle_batch([(FLEET, ROBOT, end_of(29))], 1.0).catchups
    assert not table.release_overdue(2.9).closed  # still waiting
    late = table.release_overdue(3.1)
    [(final, _cause)] = late.closed
    assert (final.frames_applied, final.frames_missing) == (20, 10)
    store.close()


def test_a_frame_both_in_the_cache_reply_and_live_counts_once(tmp_path: Path) -> None:
    # A take-over or a restart while the robot streams: its own put of a frame races the
    # copy of the same frame in its cache's reply. Whichever comes second is dropped
    # uncounted (the robot offered the frame once), while a real repeat is still a duplicate.
    store = open_store(tmp_path)
    table = catchup_table(store)
    out = feed(table, FRAMES[:10])
    out.append(table.handle_batch([(FLEET, ROBOT, FRAMES[14])], 1.0))  # 10..13 in the cache
    out.append(table.recover((FLEET, ROBOT), SESSION, FRAMES[10:15], 1.1))  # 14 too
    out += feed(table, FRAMES[12:14], now_s=1.2)  # the robot's own puts of 12, 13, late
    out.append(table.catchup_done((FLEET, ROBOT), SESSION, 1.3))
    out += feed(table, FRAMES[15:17], now_s=1.4)
    out += feed(table, FRAMES[16:17], now_s=1.5)  # a real repeat
    assert errors(out) == [ErrorCode.DUPLICATE_SEQ]
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert (state.frames_applied, state.frames_missing, state.frames_duplicate) == (17, 0, 1)
    store.close()


def test_a_hold_is_bounded_in_time_and_in_frames(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = catchup_table(store)
    feed(table, FRAMES[:5])
    table.handle_batch([(FLEET, ROBOT, FRAMES[7])], 10.0)
    assert table.release_overdue(11.9).frames_applied == 0
    released = table.release_overdue(12.0)  # no answer within catchup_wait_s
    assert released.frames_applied == 1
    assert [r.code for r in released.rejections] == [ErrorCode.SEQ_GAP]
    assert table.holds == 0
    # A gap within catchup_wait_s of the last query is reported at once (no second query).
    quick = table.handle_batch([(FLEET, ROBOT, FRAMES[9])], 11.0)
    assert not quick.catchups
    assert errors([quick]) == [ErrorCode.SEQ_GAP]
    # Past the cool-down, a hold that grows beyond catchup_max_frames is released.
    table.handle_batch([(FLEET, ROBOT, FRAMES[11])], 20.0)
    flood = feed(table, FRAMES[12:113], now_s=20.1)
    assert table.holds == 0
    assert sum(o.frames_applied for o in flood) == 102
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert state.frames_missing == 4  # seqs 5..6, 8 and 10
    store.close()


def test_an_end_waits_for_the_catch_up_and_a_stop_releases_holds(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = catchup_table(store)
    feed(table, FRAMES[:20])
    table.handle_batch([(FLEET, ROBOT, FRAMES[25])], 1.0)
    end = SessionEnd(session=SESSION, last_seq=25, stamp_s=99.0)
    waiting = table.handle_batch([(FLEET, ROBOT, end)], 1.1)
    assert not waiting.closed
    filled = table.recover((FLEET, ROBOT), SESSION, FRAMES[15:26], 1.2)  # 20..24 were missing
    done = table.catchup_done((FLEET, ROBOT), SESSION, 1.3)
    closed = filled.closed + done.closed
    assert [(s.frames_applied, s.frames_missing, cause) for s, cause in closed] == [
        (26, 0, "ended")
    ]
    # A stop applies what is held (the gap is then reported) and checkpoints it.
    other = "r2"
    table.handle_batch([(FLEET, other, f) for f in (*FRAMES[:3], FRAMES[6])], 2.0)
    stopped = table.close_all("shutdown")
    assert [(s.robot, s.last_seq, s.frames_missing) for s in stopped.suspended] == [(other, 6, 3)]
    store.close()


def test_unneeded_cache_replies_are_dropped_silently(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = catchup_table(store)
    feed(table, FRAMES[:10])
    other_session = [f.model_copy(update={"session": "old"}) for f in FRAMES[:20]]
    nothing_held = table.recover((FLEET, ROBOT), SESSION, FRAMES[:20], 1.0)
    assert nothing_held.frames_applied == 0
    table.handle_batch([(FLEET, ROBOT, FRAMES[12])], 1.0)
    wrong = table.recover((FLEET, ROBOT), SESSION, other_session, 1.1)
    done = table.catchup_done((FLEET, ROBOT), SESSION, 1.2)
    assert wrong.frames_applied == 0
    assert [r.code for r in done.rejections] == [ErrorCode.SEQ_GAP]
    assert not errors([nothing_held, wrong])
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


def test_a_probed_end_of_a_session_open_here_is_news_and_closes_it_once(tmp_path: Path) -> None:
    # A partition taken over: the former owner's final record is open at seq 19, and the
    # robot's end (last seq 19) reached nobody live; the probe (or the frames held during
    # the hand-shake) finds it. Frames at or below 19 are no news; the end is.
    store = open_store(tmp_path)
    former = make_table(store)
    feed(former, FRAMES[:20])
    commit_checkpoints(former.hand_over(lambda _f, _r: True, 1.0), store)
    taker = make_table(store)
    assert not taker.is_news(FLEET, ROBOT, FRAMES[19])
    assert taker.is_news(FLEET, ROBOT, FRAMES[20])
    assert taker.is_news(FLEET, ROBOT, end_of(19))
    assert not taker.is_news(FLEET, ROBOT, SessionEnd(session="other", last_seq=3, stamp_s=1.0))
    [(final, cause)] = taker.handle_batch([(FLEET, ROBOT, end_of(19))], 2.0).closed
    assert cause == "ended"
    assert (final.frames_applied, final.frames_missing, final.last_seq) == (20, 0, 19)
    assert not taker.is_news(FLEET, ROBOT, end_of(19))  # closed: a repeat is no news
    store.close()

"""Durable sessions: catch-up from the robot's publication cache, and a probed end as news."""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.runtime.sessions import SessionTable, commit_checkpoints
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

    from lessmap.runtime.store import CheckpointStore


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

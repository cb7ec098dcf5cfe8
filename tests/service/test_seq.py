"""The pure seq rules of a session (sessions/seq.py): no table, no store, no Zenoh."""

from __future__ import annotations

from hypothesis import given, strategies as st

from lessmap.runtime.sessions.seq import (
    CLOSED_IDS_KEPT,
    CacheMarks,
    ClosedIds,
    Repeat,
    SeqState,
    take_from_gaps,
)

KEY = ("f", "r")


def test_in_order_seqs_reveal_no_gap() -> None:
    state = SeqState()
    assert [state.advance(seq) for seq in range(5)] == [None] * 5
    assert state.last_seen_seq == 4
    assert state.expected_seq == 5
    assert (state.frames_missing, state.frames_duplicate, state.frames_rejected) == (0, 0, 0)


def test_a_jump_counts_the_skipped_seqs_missing_once() -> None:
    state = SeqState()
    state.advance(0)
    assert state.advance(5) == (1, 4)
    assert state.frames_missing == 4
    assert list(state.gaps) == [(1, 4)]


def test_a_late_frame_moves_from_missing_to_rejected() -> None:
    state = SeqState()
    state.advance(0)
    state.advance(5)
    assert state.is_repeat(3)
    assert state.repeat(3) is Repeat.LATE
    assert (state.frames_missing, state.frames_rejected) == (3, 1)
    assert list(state.gaps) == [(1, 2), (4, 4)]
    # The same seq again is no longer in a gap: a duplicate.
    assert state.repeat(3) is Repeat.DUPLICATE
    assert state.frames_duplicate == 1


def test_a_seq_at_or_below_the_restore_point_is_a_redelivery() -> None:
    state = SeqState()
    state.restore_counters(
        {
            "frames_duplicate": 0,
            "frames_missing": 0,
            "frames_rejected": 0,
            "last_seen_seq": 9,
            "gaps": [],
        }
    )
    assert state.repeat(9) is Repeat.REDELIVERY
    assert state.frames_duplicate == 1
    assert not state.is_repeat(10)


def test_counters_survive_a_checkpoint_round_trip() -> None:
    state = SeqState()
    for seq in (0, 1, 4, 2, 2, 9):
        if state.is_repeat(seq):
            state.repeat(seq)
        else:
            state.advance(seq)
    again = SeqState()
    again.restore_counters(state.counters())
    assert again.counters() == state.counters()
    assert again.restored_seq == state.last_seen_seq == 9


@given(st.lists(st.integers(0, 60), max_size=80))
def test_every_seq_lands_in_exactly_one_counter(seqs: list[int]) -> None:
    # Received seqs are applied (first time, in order of arrival), duplicate or late; the
    # rest up to the highest seen are missing: the counters always add up.
    state = SeqState()
    applied = 0
    for seq in seqs:
        if state.is_repeat(seq):
            state.repeat(seq)
        else:
            state.advance(seq)
            applied += 1
    if state.last_seen_seq is None:
        return
    received_slots = applied + state.frames_rejected
    assert received_slots + state.frames_missing == state.last_seen_seq + 1
    assert applied + state.frames_rejected + state.frames_duplicate == len(seqs)


def test_take_from_gaps_splits_a_range() -> None:
    from collections import deque

    gaps = deque([(1, 5)])
    assert take_from_gaps(gaps, 3)
    assert list(gaps) == [(1, 2), (4, 5)]
    assert not take_from_gaps(gaps, 3)


def test_a_cache_mark_is_used_up_by_the_second_copy() -> None:
    marks = CacheMarks()
    marks.note(KEY, "s", 7)
    assert not marks.take(KEY, "s", 8)
    assert marks.take(KEY, "s", 7)
    assert not marks.take(KEY, "s", 7)
    marks.note(KEY, "s", 1)
    marks.forget(lambda fleet, robot: (fleet, robot) == KEY)
    assert not marks.take(KEY, "s", 1)


def test_closed_ids_are_bounded_per_robot_and_in_robots() -> None:
    closed = ClosedIds(max_robots=2)
    for n in range(CLOSED_IDS_KEPT + 1):
        closed.close(KEY, f"s{n}")
    assert (KEY, "s0") not in closed
    assert (KEY, f"s{CLOSED_IDS_KEPT}") in closed
    closed.close(("f", "b"), "x")
    closed.close(("f", "c"), "y")  # the oldest robot goes
    assert closed.of(KEY) == []
    closed.remember(("f", "b"), ["x", "z"])
    assert closed.of(("f", "b")) == ["x", "z"]

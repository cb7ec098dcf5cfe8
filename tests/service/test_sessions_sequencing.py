"""SessionTable sequencing (schemas/README.md §6): duplicates, gaps, late and reordered frames."""

from __future__ import annotations

import numpy as np
import pytest

from lessmap_schemas.errors import ErrorCode
from tests.service.sessions_helpers import (
    FLEET,
    INSTANCE,
    codes,
    end,
    frames_at,
    make_table,
    state_of,
)

# -- sequencing ------------------------------------------------------------------------------


def test_in_order_frames_are_all_applied() -> None:
    table = make_table()
    outcome = table.handle_batch(frames_at(0, 1, 2, 3, 4), now_s=0.0)

    assert outcome.rejections == []
    assert outcome.frames_applied == 5
    assert [s.session for s in outcome.opened] == ["s1"]
    assert len(outcome.decisions) == 5  # max_batch_frames = 1: one decision per frame
    state = state_of(table)
    assert state.open
    assert (state.session, state.instance) == ("s1", INSTANCE)
    assert (state.last_seq, state.frames_applied) == (4, 5)
    assert (state.frames_duplicate, state.frames_missing, state.frames_rejected) == (0, 0, 0)
    assert len(table) == 1
    assert table.robots() == [(FLEET, "r1")]


def test_duplicates_are_ignored_and_counted() -> None:
    table = make_table()
    table.handle_batch(frames_at(0, 1, 2), now_s=0.0)

    again = table.handle_batch(frames_at(1, 2), now_s=1.0)
    assert codes(again) == [ErrorCode.DUPLICATE_SEQ, ErrorCode.DUPLICATE_SEQ]
    assert [r.seq for r in again.rejections] == [1, 2]
    assert all(r.session == "s1" and r.robot == "r1" for r in again.rejections)
    assert (again.frames_applied, again.frames_duplicate) == (0, 2)

    same_batch = table.handle_batch(frames_at(3, 3), now_s=2.0)
    assert codes(same_batch) == [ErrorCode.DUPLICATE_SEQ]
    assert (same_batch.frames_applied, same_batch.frames_duplicate) == (1, 1)

    state = state_of(table)
    assert (state.last_seq, state.frames_applied, state.frames_duplicate) == (3, 4, 3)
    assert state.frames_missing == 0


def test_gap_is_reported_with_its_range_and_the_frame_applied() -> None:
    table = make_table()
    table.handle_batch(frames_at(0, 1), now_s=0.0)

    outcome = table.handle_batch(frames_at(4), now_s=1.0)
    [gap] = outcome.rejections
    assert gap.code is ErrorCode.SEQ_GAP
    assert gap.seq == 4  # the frame after the gap
    assert "2..3" in gap.detail
    assert (outcome.frames_missing, outcome.frames_applied) == (2, 1)
    state = state_of(table)
    assert (state.last_seq, state.frames_applied, state.frames_missing) == (4, 3, 2)


def test_first_frame_above_zero_is_a_gap_from_zero() -> None:
    table = make_table()
    outcome = table.handle_batch(frames_at(3), now_s=0.0)

    [gap] = outcome.rejections
    assert (gap.code, gap.seq) == (ErrorCode.SEQ_GAP, 3)
    assert "0..2" in gap.detail
    assert (outcome.frames_missing, outcome.frames_applied) == (3, 1)
    assert state_of(table).frames_missing == 3

    late = table.handle_batch(frames_at(0), now_s=1.0)  # 0 lies in that gap
    assert codes(late) == [ErrorCode.OUT_OF_ORDER]
    assert state_of(table).frames_applied == 1


def test_late_frame_inside_a_gap_is_out_of_order_and_ignored() -> None:
    table = make_table()
    table.handle_batch(frames_at(0), now_s=0.0)
    table.handle_batch(frames_at(3), now_s=1.0)  # 1..2 missing

    late = table.handle_batch(frames_at(1), now_s=2.0)
    assert codes(late) == [ErrorCode.OUT_OF_ORDER]
    assert late.rejections[0].seq == 1
    assert late.frames_applied == 0

    # Frames that were applied stay duplicates, even when they are below the gap.
    again = table.handle_batch(frames_at(0, 3), now_s=3.0)
    assert codes(again) == [ErrorCode.DUPLICATE_SEQ, ErrorCode.DUPLICATE_SEQ]

    state = state_of(table)
    assert (state.last_seq, state.frames_applied) == (3, 2)  # never rewritten backwards
    # The late frame is counted once: it left "missing" (2 -> 1) for "rejected".
    assert (state.frames_missing, state.frames_rejected, state.frames_duplicate) == (1, 1, 2)

    # The same late frame again is a duplicate, not a second OUT_OF_ORDER.
    twice = table.handle_batch(frames_at(1), now_s=4.0)
    assert codes(twice) == [ErrorCode.DUPLICATE_SEQ]


@pytest.mark.parametrize("seed", range(40))
def test_every_offered_frame_is_counted_exactly_once(seed: int) -> None:
    # A robot that numbers frames 0..n-1 and puts each once, through a lossy, reordering,
    # duplicating network: applied + rejected + missing = n, and the duplicates are exactly
    # the repeated deliveries.
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 60))
    delivered = [seq for seq in range(n) if rng.random() > 0.2]  # some never arrive
    repeats = [seq for seq in delivered if rng.random() < 0.15]
    stream = delivered + repeats
    order = rng.permutation(len(stream))
    stream = [stream[i] for i in order]
    table = make_table(max_batch_frames=int(rng.integers(1, 4)))
    batch = int(rng.integers(1, 6))
    for start in range(0, len(stream), batch):
        table.handle_batch(frames_at(*stream[start : start + batch]), now_s=float(start))
    table.handle_batch([(FLEET, "r1", end(n - 1))], now_s=1000.0)
    state = state_of(table)
    assert state.frames_applied + state.frames_rejected + state.frames_missing == n, state
    # Every delivery is applied, rejected (late) or a duplicate: nothing counted twice.
    assert state.frames_applied + state.frames_rejected + state.frames_duplicate == len(stream)
    assert state.frames_missing == n - len(set(delivered))  # exactly the lost seqs


def test_reordering_inside_one_batch_loses_nothing() -> None:
    table = make_table()
    outcome = table.handle_batch(frames_at(3, 1, 2, 0), now_s=0.0)

    assert outcome.rejections == []
    assert (outcome.frames_applied, outcome.frames_missing) == (4, 0)
    state = state_of(table)
    assert (state.last_seq, state.frames_applied, state.frames_missing) == (3, 4, 0)

"""SessionTable decisions: equal to the offline loop, coalesced, independent across robots."""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, cast

import numpy as np
import pytest

from lessmap.core import Partitioner, Reason, Transition
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Frame
from tests.service.sessions_helpers import (
    FLEET,
    LASER,
    Message,
    codes,
    frames_at,
    make_table,
    msgs,
    room_walk,
    state_of,
    walk_frames,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.runtime.sessions import Outcome


def reference(walk: Sequence[Sequence[int]]) -> list[Transition]:
    """The transitions of the offline per-frame loop (``Partitioner.observe``)."""
    partitioner = Partitioner(LASER)
    found = []
    for seq, features in enumerate(walk):
        transition = partitioner.observe(seq, float(seq), features)
        if transition is not None:
            found.append(transition)
    return found


def essentials(transition: Transition) -> tuple[object, ...]:
    return (
        transition.seq,
        transition.boundary_seq,
        transition.reason,
        transition.ncut,
        transition.lambda2,
        transition.closed.features,
        transition.opened.features,
    )


def transitions_of(outcomes: Sequence[Outcome], robot: str = "r1") -> list[Transition]:
    return [c.transition for o in outcomes for s, c in o.transitions if s.robot == robot]


# -- equivalence with the offline loop -------------------------------------------------------


def batches(items: Sequence[Message], sizes: Sequence[int]) -> list[list[Message]]:
    out: list[list[Message]] = []
    start = 0
    for size in itertools.cycle(sizes):
        if start >= len(items):
            return out
        out.append(list(items[start : start + size]))
        start += size
    raise AssertionError  # pragma: no cover - cycle never ends


@pytest.mark.parametrize(("rooms", "seed"), [(2, None), (3, 1)])
@pytest.mark.parametrize("sizes", [(1,), (7,), (100,), "random"], ids=str)
def test_decide_at_every_frame_equals_the_offline_loop(
    rooms: int, seed: int | None, sizes: tuple[int, ...] | str
) -> None:
    walk = room_walk(rooms, seed=seed)
    expected = reference(walk)
    assert len(expected) == rooms - 1
    assert all(t.reason is Reason.SPECTRAL for t in expected)

    rng = np.random.default_rng(0 if seed is None else seed)
    cut = [int(n) for n in rng.integers(1, 12, size=len(walk))] if sizes == "random" else sizes
    assert not isinstance(cut, str)
    table = make_table(max_batch_frames=1)
    outcomes = []
    for now, batch in enumerate(batches(msgs("r1", *walk_frames(walk)), cut)):
        shuffled = [batch[i] for i in rng.permutation(len(batch))]  # reordered inside a batch
        outcomes.append(table.handle_batch(shuffled, now_s=float(now)))

    found = transitions_of(outcomes)
    assert [essentials(t) for t in found] == [essentials(t) for t in expected]
    assert found == expected  # every field, including batch_frames == 1 and the stamps
    assert all(o.rejections == [] for o in outcomes)
    assert sum(o.frames_applied for o in outcomes) == len(walk)
    state = state_of(table)
    assert (state.frames_applied, state.transitions) == (len(walk), len(expected))


def test_coalesced_batch_still_finds_the_transition() -> None:
    walk = room_walk(2)
    [expected] = reference(walk)
    table = make_table(max_batch_frames=8)

    outcome = table.handle_batch(msgs("r1", *walk_frames(walk)), now_s=0.0)

    [(session, change)] = outcome.transitions
    found = change.transition
    assert session.session == "s1"
    assert found.batch_frames > 1
    assert found.reason is expected.reason
    assert found.closed.features == expected.closed.features
    assert found.opened.features == expected.opened.features
    assert found.seq - found.batch_frames < expected.seq <= found.seq
    assert outcome.frames_applied == len(walk)
    assert outcome.rejections == []
    assert [frames for _, frames in outcome.decisions] == [8] * 7 + [5]
    state = state_of(table)
    assert (state.frames_applied, state.last_seq, state.transitions) == (61, 60, 1)


def test_coalesced_transitions_come_in_increasing_seq_order() -> None:
    walk = room_walk(3, seed=4)
    table = make_table(max_batch_frames=5)
    outcomes = [
        table.handle_batch(batch, now_s=float(i))
        for i, batch in enumerate(batches(msgs("r1", *walk_frames(walk)), (13,)))
    ]
    seqs = [t.seq for t in transitions_of(outcomes)]
    assert len(seqs) == 2
    assert seqs == sorted(set(seqs))
    assert sum(o.frames_applied for o in outcomes) == len(walk)


# -- robots are independent ------------------------------------------------------------------


def test_two_robots_in_one_batch_never_cross_talk() -> None:
    # Same feature IDs for both robots, walked in opposite directions: any shared state
    # between their CovGraphs would change the decisions.
    walk_a = room_walk(3, seed=5)
    walk_b = [list(f) for f in reversed(room_walk(3, seed=6))]
    interleaved = [
        m
        for pair in itertools.zip_longest(
            msgs("a", *walk_frames(walk_a)), msgs("b", *walk_frames(walk_b))
        )
        for m in pair
        if m is not None
    ]
    table = make_table()
    outcomes = [
        table.handle_batch(batch, now_s=float(i))
        for i, batch in enumerate(batches(interleaved, (9,)))
    ]

    assert transitions_of(outcomes, "a") == reference(walk_a)
    assert transitions_of(outcomes, "b") == reference(walk_b)
    assert len(reference(walk_b)) >= 1
    assert all(o.rejections == [] for o in outcomes)
    assert state_of(table, "a").frames_applied == len(walk_a)
    assert state_of(table, "b").frames_applied == len(walk_b)


def test_invalid_features_reject_one_frame_and_spare_other_robots() -> None:
    # The wire model bounds feature IDs to int64, so a Frame built without validation stands
    # in for a decoder that let one through: the core refuses it (GraphError).
    bad = Frame.model_construct(session="s1", seq=1, stamp_s=1.0, features=[2**63])
    table = make_table()
    table.handle_batch(frames_at(0, robot="bad") + frames_at(0, robot="good"), now_s=0.0)

    outcome = table.handle_batch(
        [(FLEET, "bad", bad), *frames_at(1, robot="good"), *frames_at(2, robot="bad")],
        now_s=1.0,
    )
    # The refused frame 1 counts as received: no gap before frame 2.
    [invalid] = outcome.rejections
    assert (invalid.code, invalid.robot, invalid.seq) == (ErrorCode.INVALID, "bad", 1)
    assert outcome.failures == []
    assert state_of(table, "bad").frames_rejected == 1
    assert state_of(table, "bad").last_seq == 2
    assert state_of(table, "good").last_seq == 1


def test_internal_failure_resets_one_session_and_spares_other_robots() -> None:
    # No valid message makes the core raise anything but GraphError, so an unvalidated Frame
    # (a stamp that is not a number) makes Partitioner.apply fail with a ValueError: the
    # table must contain it to that robot.
    not_a_number = cast("float", "later")
    broken = Frame.model_construct(session="s1", seq=1, stamp_s=not_a_number, features=[1, 2])
    walk = room_walk(2)
    table = make_table()
    table.handle_batch(frames_at(0, robot="bad"), now_s=0.0)

    first = table.handle_batch(
        [(FLEET, "bad", broken), *msgs("good", *walk_frames(walk)[:40])], now_s=1.0
    )
    [(key, exc)] = first.failures
    assert key == (FLEET, "bad")
    assert isinstance(exc, ValueError)
    [internal] = first.rejections
    assert (internal.code, internal.robot, internal.session) == (ErrorCode.INTERNAL, "bad", "s1")
    assert table.state(FLEET, "bad") is None  # the suspect session was dropped
    assert len(table) == 1

    rest = table.handle_batch(msgs("good", *walk_frames(walk)[40:]), now_s=2.0)
    assert transitions_of([first, rest], "good") == reference(walk)
    assert state_of(table, "good").frames_applied == len(walk)

    # The robot can go on with a new session.
    again = table.handle_batch(frames_at(0, robot="bad", session="s2"), now_s=3.0)
    assert again.rejections == []
    assert state_of(table, "bad").session == "s2"


def test_a_refused_frame_after_a_gap_does_not_count_the_gap_twice() -> None:
    # Frames 1..3 never get applied: 0, then an unvalidated frame 3 the core refuses, then 4.
    # Frames 1 and 2 are missing (one gap, counted once); frame 3 was received and refused,
    # so it counts as rejected, not missing.
    bad = Frame.model_construct(session="s1", seq=3, stamp_s=3.0, features=[2**63])
    table = make_table()
    outcome = table.handle_batch([*frames_at(0), (FLEET, "r1", bad), *frames_at(4)], now_s=0.0)

    assert ErrorCode.INVALID in codes(outcome)
    assert codes(outcome).count(ErrorCode.SEQ_GAP) == 1
    assert outcome.frames_missing == 2
    state = state_of(table)
    assert (state.frames_missing, state.frames_rejected, state.last_seq) == (2, 1, 4)

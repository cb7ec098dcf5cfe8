"""SessionTable: the ordering contract of schemas/README.md §6, limits, coalescing, isolation.

No mocks and no Zenoh: the table is sans-IO, so these tests feed it real ``Frame`` and
``SessionEnd`` messages and compare what it decides with a standalone core ``Partitioner``.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, cast

import numpy as np
import pytest

from lessmap.core import Partitioner, PartitionParams, Reason, Transition
from lessmap.core.segmenter import Method
from lessmap.runtime.sessions import Identity, Outcome, Segmenting, SessionLimits, SessionTable
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap_schemas.messages import SessionState

FLEET = "fleet"
INSTANCE = "test-instance"
LASER = PartitionParams.from_profile("laser")

Message = tuple[str, str, Frame | SessionEnd]

# -- builders --------------------------------------------------------------------------------


def make_table(
    *,
    max_sessions: int = 8,
    max_nodes: int = 10_000,
    max_batch_frames: int = 1,
    idle_timeout_s: float = 60.0,
    params: PartitionParams = LASER,
) -> SessionTable:
    # The paper, as the offline `Partitioner` these tests compare with (areas sessions:
    # test_areas_sessions.py).
    return SessionTable(
        Segmenting(params=params, method=Method.PAPER),
        SessionLimits(
            max_sessions=max_sessions,
            max_nodes=max_nodes,
            max_batch_frames=max_batch_frames,
            idle_timeout_s=idle_timeout_s,
        ),
        identity=Identity(instance=INSTANCE),
    )


def frame(seq: int, features: Sequence[int] = (1, 2, 3), session: str = "s1") -> Frame:
    return Frame(session=session, seq=seq, stamp_s=float(seq), features=list(features))


def end(last_seq: int | None, session: str = "s1") -> SessionEnd:
    return SessionEnd(session=session, last_seq=last_seq, stamp_s=1000.0)


def msgs(robot: str, *messages: Frame | SessionEnd) -> list[Message]:
    return [(FLEET, robot, m) for m in messages]


def frames_at(*seqs: int, session: str = "s1", robot: str = "r1") -> list[Message]:
    return msgs(robot, *(frame(s, session=session) for s in seqs))


def codes(outcome: Outcome) -> list[ErrorCode]:
    return [r.code for r in outcome.rejections]


def state_of(table: SessionTable, robot: str = "r1") -> SessionState:
    state = table.state(FLEET, robot)
    assert state is not None
    return state


def room_walk(rooms: int = 2, *, stay: int = 30, seed: int | None = None) -> list[list[int]]:
    """Room k has features 10k..10k+9, seen for ``stay`` frames; between two rooms one door
    frame sees 10k+7..10k+12 (a small overlap). With a seed, each frame sees each feature of
    its room with probability 0.8 instead of all of them."""
    rng = np.random.default_rng(seed) if seed is not None else None
    frames: list[list[int]] = []
    for room in range(rooms):
        features = list(range(10 * room, 10 * room + 10))
        for _ in range(stay):
            seen = features if rng is None else [f for f in features if rng.random() < 0.8]
            frames.append(list(seen))
        if room + 1 < rooms:
            frames.append(list(range(10 * room + 7, 10 * room + 13)))
    return frames


def walk_frames(walk: Sequence[Sequence[int]], session: str = "s1") -> list[Frame]:
    return [frame(seq, features, session) for seq, features in enumerate(walk)]


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


# -- session lifecycle -----------------------------------------------------------------------


def test_new_session_id_replaces_the_open_session() -> None:
    table = make_table()
    table.handle_batch(msgs("r1", *(frame(s, (1, 2, 3)) for s in range(3))), now_s=0.0)

    outcome = table.handle_batch(msgs("r1", frame(0, (7, 8), session="s2")), now_s=1.0)

    [(final, cause)] = outcome.closed
    assert cause == "replaced"
    assert (final.session, final.open) == ("s1", False)
    assert (final.last_seq, final.frames_applied, final.nodes) == (2, 3, 3)
    assert [s.session for s in outcome.opened] == ["s2"]
    assert outcome.rejections == []
    state = state_of(table)
    assert (state.session, state.open) == ("s2", True)
    # A new CovGraph: nothing of s1's features, seq starts again at 0 without a gap.
    assert (state.last_seq, state.frames_applied, state.nodes) == (0, 1, 2)
    assert state.current_submap.features == [7, 8]
    assert len(table) == 1


def test_frames_of_a_closed_session_are_rejected() -> None:
    table = make_table()
    table.handle_batch(frames_at(0, 1), now_s=0.0)
    table.handle_batch(frames_at(0, session="s2"), now_s=1.0)

    outcome = table.handle_batch(frames_at(2, 3), now_s=2.0)
    assert codes(outcome) == [ErrorCode.SESSION_CLOSED, ErrorCode.SESSION_CLOSED]
    assert [r.seq for r in outcome.rejections] == [2, 3]
    assert all(r.session == "s1" for r in outcome.rejections)
    assert outcome.closed == []  # s2 stays open: a closed id never reopens or replaces
    assert outcome.opened == []
    assert state_of(table).session == "s2"

    # The same within one batch: s1, then s2 replaces it, then a straggler of s1.
    table = make_table()
    mixed = table.handle_batch(
        msgs("r1", frame(0), frame(0, session="s2"), frame(1), frame(1, session="s2")),
        now_s=0.0,
    )
    assert codes(mixed) == [ErrorCode.SESSION_CLOSED]
    assert mixed.rejections[0].seq == 1
    state = state_of(table)
    assert (state.session, state.frames_applied, state.last_seq) == ("s2", 2, 1)


def test_session_end_closes_the_session() -> None:
    table = make_table()
    table.handle_batch(frames_at(0, 1, 2), now_s=0.0)

    outcome = table.handle_batch(msgs("r1", end(2)), now_s=1.0)
    assert outcome.rejections == []
    assert outcome.transitions == []  # no transition for the end of a session
    [(final, cause)] = outcome.closed
    assert cause == "ended"
    assert (final.session, final.open, final.last_seq, final.frames_missing) == (
        "s1",
        False,
        2,
        0,
    )
    assert len(table) == 0
    assert table.state(FLEET, "r1") == final

    after = table.handle_batch(frames_at(3), now_s=2.0)
    assert codes(after) == [ErrorCode.SESSION_CLOSED]
    assert after.opened == []


def test_frames_and_end_in_one_batch_then_a_straggler() -> None:
    table = make_table()
    outcome = table.handle_batch(msgs("r1", frame(1), frame(0), end(1), frame(2)), now_s=0.0)

    assert codes(outcome) == [ErrorCode.SESSION_CLOSED]
    assert outcome.rejections[0].seq == 2
    [(final, cause)] = outcome.closed
    assert (cause, final.frames_applied, final.last_seq) == ("ended", 2, 1)


def test_a_cache_copy_behind_the_end_of_its_session_is_a_redelivery() -> None:
    # A take-over's probe judged the cache's copy of frame 2 news while the session was
    # open; the robot's own frame 2 and its end came first. The copy meets the closed
    # session: a frame applied once, not a straggler (no SESSION_CLOSED, nothing counted).
    table = make_table()
    table.note_from_cache((FLEET, "r1"), "s1", 2)
    outcome = table.handle_batch(msgs("r1", frame(0), frame(1), frame(2), end(2), frame(2)), 0.0)
    assert codes(outcome) == []
    final = state_of(table)
    assert (final.open, final.frames_applied, final.frames_rejected) == (False, 3, 0)
    assert final.frames_duplicate == 0
    # The mark was used up: the robot's own frame 2 once more, or a frame past the end,
    # is a straggler of the closed session as before.
    again = table.handle_batch(frames_at(2, 3), now_s=1.0)
    assert codes(again) == [ErrorCode.SESSION_CLOSED, ErrorCode.SESSION_CLOSED]
    assert state_of(table).frames_rejected == 2


def test_session_end_beyond_the_last_frame_counts_the_tail_missing() -> None:
    table = make_table()
    table.handle_batch(frames_at(0, 1, 2), now_s=0.0)

    outcome = table.handle_batch(msgs("r1", end(6)), now_s=1.0)
    [gap] = outcome.rejections
    assert (gap.code, gap.seq, gap.session) == (ErrorCode.SEQ_GAP, 6, "s1")
    assert outcome.frames_missing == 4
    assert "3..6" in gap.detail  # a SEQ_GAP detail names the range (README §6.2)
    [(final, cause)] = outcome.closed
    assert cause == "ended"
    assert (final.frames_missing, final.last_seq, final.open) == (4, 2, False)


def test_session_end_of_an_opened_session_without_frames_applied() -> None:
    # A session whose only frame hit the graph limit is open with no frame applied.
    table = make_table(max_nodes=2)
    first = table.handle_batch(msgs("r1", frame(0, (1, 2, 3))), now_s=0.0)
    assert codes(first) == [ErrorCode.GRAPH_LIMIT]

    # Frame 0 was received (and refused): only frame 1 is missing.
    outcome = table.handle_batch(msgs("r1", end(1)), now_s=1.0)
    [gap] = outcome.rejections
    assert gap.code is ErrorCode.SEQ_GAP
    assert outcome.frames_missing == 1
    assert "1..1" in gap.detail
    assert "None" not in gap.detail  # no Python repr in an operator-facing message
    [(final, _)] = outcome.closed
    assert (final.last_seq, final.frames_applied, final.frames_rejected) == (None, 0, 1)


def test_repeated_or_unknown_session_end_is_ignored() -> None:
    table = make_table()
    table.handle_batch(msgs("r1", frame(0), end(0)), now_s=0.0)

    repeated = table.handle_batch(msgs("r1", end(0), end(5)), now_s=1.0)
    unknown = table.handle_batch(msgs("r1", end(3, session="never-seen")), now_s=2.0)
    other_robot = table.handle_batch(msgs("r2", end(None, session="x")), now_s=3.0)

    for outcome in (repeated, unknown, other_robot):
        assert outcome.rejections == []
        assert outcome.closed == []
        assert outcome.opened == []
        assert outcome.frames_missing == 0
    assert state_of(table).frames_missing == 0
    assert table.state(FLEET, "r2") is None
    assert len(table) == 0


def test_session_limit_refuses_new_sessions() -> None:
    table = make_table(max_sessions=2)
    table.handle_batch(frames_at(0, robot="r1") + frames_at(0, robot="r2"), now_s=0.0)

    outcome = table.handle_batch(frames_at(0, robot="r3"), now_s=1.0)
    [refused] = outcome.rejections
    assert (refused.code, refused.robot, refused.seq) == (ErrorCode.SESSION_LIMIT, "r3", 0)
    assert outcome.opened == []
    assert outcome.frames_applied == 0
    assert table.state(FLEET, "r3") is None
    assert len(table) == 2

    # Replacing a robot's own session is not a new session for the limit.
    replaced = table.handle_batch(frames_at(0, robot="r1", session="s2"), now_s=2.0)
    assert replaced.rejections == []
    assert [cause for _, cause in replaced.closed] == ["replaced"]
    assert len(table) == 2

    # Once a session ends, there is room again.
    table.handle_batch(msgs("r2", end(0)), now_s=3.0)
    admitted = table.handle_batch(frames_at(0, robot="r3"), now_s=4.0)
    assert admitted.rejections == []
    assert state_of(table, "r3").open


def test_graph_limit_refuses_the_frame() -> None:
    table = make_table(max_nodes=15)
    table.handle_batch(msgs("r1", frame(0, range(10))), now_s=0.0)

    outcome = table.handle_batch(msgs("r1", frame(1, range(10, 20))), now_s=1.0)
    [refused] = outcome.rejections
    assert (refused.code, refused.seq) == (ErrorCode.GRAPH_LIMIT, 1)
    assert outcome.frames_applied == 0
    state = state_of(table)
    assert (state.last_seq, state.frames_applied, state.frames_rejected) == (0, 1, 1)
    assert state.nodes == 10

    # Known features still fit: the session goes on.
    ok = table.handle_batch(msgs("r1", frame(2, range(5, 15))), now_s=2.0)  # 10 + 5 = 15
    assert ErrorCode.GRAPH_LIMIT not in codes(ok)
    assert ok.frames_applied == 1
    assert (state_of(table).last_seq, state_of(table).nodes) == (2, 15)


def test_expire_idle_closes_only_idle_sessions() -> None:
    table = make_table(idle_timeout_s=60.0)
    table.handle_batch(frames_at(0, robot="r1"), now_s=0.0)
    table.handle_batch(frames_at(0, robot="r2"), now_s=40.0)
    table.handle_batch(frames_at(0, robot="r3"), now_s=50.0)

    assert table.expire_idle(now_s=60.0).closed == []  # idle for exactly the timeout: kept
    outcome = table.expire_idle(now_s=100.5)
    assert [(s.robot, cause) for s, cause in outcome.closed] == [
        ("r1", "idle"),
        ("r2", "idle"),
    ]
    assert all(not s.open for s, _ in outcome.closed)
    assert len(table) == 1
    assert state_of(table, "r3").open
    assert not state_of(table, "r1").open

    # Activity keeps a session alive, and an expired session id never comes back.
    table.handle_batch(frames_at(1, robot="r3"), now_s=100.0)
    assert table.expire_idle(now_s=150.0).closed == []
    straggler = table.handle_batch(frames_at(1, robot="r1"), now_s=150.0)
    assert codes(straggler) == [ErrorCode.SESSION_CLOSED]


def test_close_all_closes_every_session() -> None:
    table = make_table()
    table.handle_batch(frames_at(0, robot="r1") + frames_at(0, 1, robot="r2"), now_s=0.0)

    outcome = table.close_all("shutdown")
    assert sorted((s.robot, s.open, cause) for s, cause in outcome.closed) == [
        ("r1", False, "shutdown"),
        ("r2", False, "shutdown"),
    ]
    assert len(table) == 0
    assert sorted(table.robots()) == [(FLEET, "r1"), (FLEET, "r2")]
    assert state_of(table, "r2").frames_applied == 2
    assert table.close_all("shutdown").closed == []


# -- queries ---------------------------------------------------------------------------------


def test_state_and_submap_queries_for_open_and_closed_sessions() -> None:
    table = make_table()
    assert table.state(FLEET, "r1") is None
    assert table.submap(FLEET, "r1", 0) is None

    outcome = table.handle_batch(msgs("r1", *walk_frames(room_walk())), now_s=0.0)
    [(_, change)] = outcome.transitions
    transition = change.transition

    state = state_of(table)
    assert state.open
    assert (state.transitions, state.frames_applied) == (1, 61)
    assert state.current_submap.id == 1
    assert [s.id for s in state.closed_submaps] == [0]

    found = table.submap(FLEET, "r1", 1)
    assert found is not None
    assert found[0] == state
    assert found[1] == state.current_submap
    assert found[2] is True
    assert found[1].features == list(transition.opened.features)

    closed = table.submap(FLEET, "r1", 0)
    assert closed is not None
    assert closed[1].features == list(transition.closed.features)
    assert closed[2] is False
    assert table.submap(FLEET, "r1", 7) is None
    assert table.submap(FLEET, "nobody", 0) is None
    assert table.state(FLEET, "r1") == state  # queries are read-only

    table.handle_batch(msgs("r1", end(60)), now_s=1.0)
    final = state_of(table)
    assert not final.open
    after = table.submap(FLEET, "r1", 1)
    assert after is not None
    assert after[1] == final.current_submap
    assert after[2] is False  # the session is closed, so its last submap is too
    closed_after = table.submap(FLEET, "r1", 0)
    assert closed_after is not None
    assert closed_after[2] is False
    assert table.submap(FLEET, "r1", 2) is None


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

"""SessionTable lifecycle: sessions replaced and ended, limits, idle expiry, close, queries."""

from __future__ import annotations

from lessmap_schemas.errors import ErrorCode
from tests.service.sessions_helpers import (
    FLEET,
    codes,
    end,
    frame,
    frames_at,
    make_table,
    msgs,
    room_walk,
    state_of,
    walk_frames,
)

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

"""Incarnations: after lost history a session's transitions never reuse a published identity.

A table that resumes from a checkpoint, or starts without one, and whose first frame follows
a gap, starts a new incarnation at that frame with an empty segmenter (schemas/README.md,
section 6 rule 10). Whatever it resumed from, the same frames from there give the same
transitions under the same identities.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.runtime.sessions.wire import wire_transition
from lessmap_schemas.errors import ErrorCode
from tests.service.durable_helpers import (
    FLEET,
    FRAMES,
    REFERENCE,
    ROBOT,
    crash,
    errors,
    feed,
    make_table,
    open_store,
    transitions,
)
from tests.service.identities import content_of, identity_of

if TYPE_CHECKING:
    from pathlib import Path

    from lessmap.runtime.sessions.model import Outcome
    from lessmap_schemas.messages import Transition


def wire(outcomes: list[Outcome]) -> list[Transition]:
    return [wire_transition(s, c, "test") for o in outcomes for s, c in o.transitions]


def conflicts(*runs: list[Transition]) -> int:
    seen: dict[object, object] = {}
    found = 0
    for t in (t for run in runs for t in run):
        first = seen.setdefault(identity_of(t), content_of(t))
        found += first != content_of(t)
    return found


def resumed_then_gap(folder: Path, checkpoint_at: int, restart_at: int) -> list[Transition]:
    """A run that dies after ``checkpoint_at`` frames, then sees frames from ``restart_at``."""
    store = open_store(folder)
    table = make_table(store, every=25)
    feed(table, FRAMES[:checkpoint_at])
    assert store.flush()
    crash(store)
    store = open_store(folder)
    table = make_table(store, every=25)
    after = feed(table, FRAMES[restart_at:])
    assert after[0].resumed, "the session resumed from its checkpoint"
    assert ErrorCode.SEQ_GAP in errors(after)
    store.close()
    return wire(after)


def test_a_whole_session_is_incarnation_0() -> None:
    run = wire(feed(make_table(None), FRAMES))
    assert run
    assert {t.incarnation for t in run} == {0}


def test_a_gap_after_a_resume_starts_a_new_incarnation_from_an_empty_segmenter(
    tmp_path: Path,
) -> None:
    restart_at = 250
    before = wire(feed(make_table(None), FRAMES))  # what the lost process published
    after = resumed_then_gap(tmp_path, 100, restart_at)
    assert after
    assert {t.incarnation for t in after} == {restart_at}
    # The new incarnation stands on the frames from ``restart_at`` on, as a fresh session.
    fresh = transitions(feed(make_table(None), FRAMES[restart_at:]))
    assert [(t.seq, t.closed.id, tuple(t.closed.features)) for t in after] == fresh
    assert conflicts(before, after) == 0


def test_two_resume_points_before_one_gap_give_the_same_identities_and_content(
    tmp_path: Path,
) -> None:
    first = resumed_then_gap(tmp_path / "a", 50, 300)
    second = resumed_then_gap(tmp_path / "b", 200, 300)
    assert first
    assert [identity_of(t) for t in first] == [identity_of(t) for t in second]
    assert conflicts(first, second) == 0


def test_a_start_without_checkpoint_after_a_gap_is_a_new_incarnation(tmp_path: Path) -> None:
    resumed = resumed_then_gap(tmp_path / "a", 100, 300)
    fresh = wire(feed(make_table(None), FRAMES[300:]))  # the store was lost entirely
    assert {t.incarnation for t in fresh} == {300}
    assert conflicts(resumed, fresh) == 0
    assert [content_of(t) for t in resumed] == [content_of(t) for t in fresh]


def test_a_resume_without_a_gap_keeps_the_incarnation_and_the_history(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = make_table(store, every=25)
    feed(table, FRAMES[:230])
    assert store.flush()
    crash(store)
    store = open_store(tmp_path)
    table = make_table(store, every=25)
    after = wire(feed(table, FRAMES[225:]))  # the cache reaches back to the checkpoint
    assert {t.incarnation for t in after} == {0}
    assert [(t.seq, t.closed.id, tuple(t.closed.features)) for t in after] == [
        r for r in REFERENCE if r[0] >= 225
    ]
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert state.incarnation == 0
    store.close()


def test_the_incarnation_and_the_counts_survive_a_checkpoint(tmp_path: Path) -> None:
    resumed_then_gap(tmp_path, 100, 250)  # incarnation 250, checkpointed as it goes
    store = open_store(tmp_path)
    table = make_table(store, every=25)
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert state.incarnation == 250
    # Every seq is applied (in either incarnation) or missing, each once.
    assert (state.frames_applied, state.frames_missing) == (100 + len(FRAMES) - 250, 150)
    store.close()

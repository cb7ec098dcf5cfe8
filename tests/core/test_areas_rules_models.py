"""AreaTracker rules 5-9: recognition, merging, accounting and seams, snapshots, bounds."""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING

import numpy as np
import pytest

from lessmap.core import GraphError
from lessmap.core.areas.rules import seam
from lessmap.core.areas.snapshot import from_bytes, to_bytes
from lessmap.core.areas.tracker import (
    AreaParams,
    AreaReason,
    AreaTracker,
    Rule,
    profile,
    rate_overlap,
)
from tests.core.areas_rules_helpers import H2, A, B, moves, stay, track, wide_door
from tests.core.helpers import room_walk

if TYPE_CHECKING:
    from tests.core.helpers import Frames


# -- rule 5: recognition -------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_a_known_room_is_recognised_through_a_wide_door(seed: int) -> None:
    # A, a wide door into B, B, a wide door back into A: the room left behind stays in view,
    # so the paper's test cannot split; the frames fit area 0's profile far better.
    rng = np.random.default_rng(seed)
    frames = [
        *stay(rng, A, 30),
        *wide_door(rng, B, A),
        *stay(rng, B, 20),
        *wide_door(rng, A, B),
        *stay(rng, A, 20),
    ]
    _, found = track(frames)
    assert moves(found) == [(0, 1), (1, 0)]
    back = found[1]
    assert back.rule is Rule.RECOGNISED
    assert back.revisit_of == 0
    assert 60 <= back.transition.boundary_seq <= back.transition.seq <= 70
    assert back.reason is AreaReason.RECOGNISED  # no Eq. 4 test ran
    assert back.transition.ncut is None
    assert back.transition.lambda2 is None
    assert found[0].rule is Rule.SPLIT
    assert str(found[0].reason) == str(found[0].transition.reason)  # a split: the paper's
    assert len(back.transition.closed.features) >= 5
    _, unrecognised = track(frames, AreaParams(recognise_frames=0))
    assert all(change.transition.seq > 70 for change in unrecognised[1:])


def test_a_profile_scores_a_frame_by_its_sightings() -> None:
    counts = {1: 9, 2: 1}  # ten frames: feature 1 in nine, feature 2 in one
    fit = profile(counts, 10)
    assert fit is not None
    # p(1) = 9.5 / 11, p(2) = 1.5 / 11, never-seen features 0.5 / 11
    expected = np.log(9.5 / 11) + np.log(1 - 1.5 / 11) + np.log(0.5 / 11)
    assert fit.loglik([1, 3]) == pytest.approx(expected)
    assert fit.loglik([1]) > fit.loglik([2]) > fit.loglik([3])
    left_out = profile(counts, 10, leave={1: 9, 2: 1}, left=10)
    assert left_out is None  # every frame left out: nothing to fit


# -- rule 6: merging -----------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
def test_two_halves_of_one_room_merge(seed: int) -> None:
    # Half A, then half H2 (a split: H2 was never seen), then the middle of the room (both
    # halves), then half A again: its frames fit area 0, but areas 0 and 1 share their
    # sightings, so they are one area and the return is no transition.
    rng = np.random.default_rng(seed)
    frames = [
        *stay(rng, A, 30),
        *stay(rng, H2, 30),
        *stay(rng, A | H2, 30, p=0.6),
        *stay(rng, A, 30),
    ]
    tracker, found = track(frames)
    assert moves(found) == [(0, 1)]
    assert tracker.merged == {1: 0}
    assert (tracker.area_count, tracker.current, tracker.area_of(1)) == (1, 0, 0)
    assert set(tracker.area_features(1)) == A | H2
    _, unmerged = track(frames, AreaParams(merge_overlap=2.0))
    assert moves(unmerged) == [(0, 1), (1, 0)]
    assert unmerged[1].rule is Rule.RECOGNISED


def test_rate_overlap_by_hand() -> None:
    a = {1: 8, 2: 8}  # ten frames: 0.8 and 0.8
    b = {2: 2, 3: 4}  # four frames: 0.5 and 1.0
    # shared min(0.8, 0.5) = 0.5 over min(1.6, 1.5)
    assert rate_overlap(a, 10, b, 4) == pytest.approx(0.5 / 1.5)
    assert rate_overlap(a, 10, a, 10) == pytest.approx(1.0)
    assert rate_overlap(a, 10, {}, 0) == 0.0


# -- rule 7: the area model accounts for every frame ---------------------------------------


@pytest.mark.parametrize("seed", range(4))
def test_every_sighting_belongs_to_exactly_one_area(seed: int) -> None:
    walk = room_walk(seed, rooms=5, back=True, stay=(15, 30), door_frames=3, door_share=0.3)
    rng = np.random.default_rng(seed)
    frames = [[] if rng.random() < 0.05 else frame for frame in walk.frames]
    tracker = AreaTracker()
    sightings: Counter[int] = Counter()
    nonempty = 0
    for seq, frame in enumerate(frames):
        change = tracker.observe(seq, float(seq), frame)
        sightings.update(set(frame))
        nonempty += bool(frame)
        assert sum(tracker.area_frames) == nonempty
        total: Counter[int] = Counter()
        for counts in tracker.areas:
            total.update(counts)
        assert total == sightings
        assert tracker.current not in tracker.merged
        assert all(not tracker.areas[gone] for gone in tracker.merged)
        if change is not None:
            assert len(change.transition.closed.features) >= 5
            assert change.area == tracker.current != change.left_area


def test_the_seam_is_where_the_two_sides_share_most_features() -> None:
    frames: list[tuple[int, tuple[int, ...]]] = [(0, (1, 2, 3)), (1, (1, 2, 3)), (2, (1, 2, 3))]
    frames += [(3, (1, 2, 3))]
    frames += [(4, (1, 2, 3, 4, 5)), (5, (1, 2, 4, 5)), (6, (4, 5, 6))]
    frames += [(7, (4, 5, 6)), (8, (4, 5, 6)), (9, (4, 5, 6))]
    counts = dict(Counter(f for _, features in frames for f in features))
    # shared within 2 frames: 3 at frame 4 ({1, 2, 3}), 4 at 5 ({1, 2, 4, 5}), 2 at 6
    assert seam(frames, counts, 4, 2, 3) == 5
    assert seam(frames, counts, 4, 0, 3) == 4  # off
    assert seam(frames, counts, 4, 2, 6) == 4  # 5 would leave 5 features on either side
    # from 6: 2 at 6, 3 at 7 and 8 (the earliest wins); never frame 5 (4), before it
    assert seam(frames, counts, 6, 2, 3) == 7
    assert seam(frames, counts, 9, 2, 3) == 9  # nothing kept after the last frame
    assert seam(frames, counts, 42, 2, 3) == 42  # not a kept frame


@pytest.mark.parametrize("seed", range(3))
def test_segments_meet_at_the_seam_and_areas_at_the_boundary(seed: int) -> None:
    # A 360° door: B's frames still see A, fading. The area entered takes the frames from
    # the boundary on; the segment entered starts at the seam, after the frames that see
    # most of both rooms, so the two segments share more features.
    rng = np.random.default_rng(seed)
    frames = [*stay(rng, A, 40), *wide_door(rng, B, A), *stay(rng, B, 30)]
    width = AreaParams().seam_frames
    assert width > 0
    tracker, found = track(frames)
    plain, unseamed = track(frames, AreaParams(seam_frames=0))
    assert moves(found) == moves(unseamed) == [(0, 1)]
    assert tracker.areas == plain.areas  # the area model does not move
    assert tracker.area_frames == plain.area_frames
    t, u = found[0].transition, unseamed[0].transition
    assert t.seq == u.seq
    assert u.boundary_seq <= t.boundary_seq <= min(u.boundary_seq + width, t.seq)
    assert t.opened.first_seq == t.boundary_seq == t.closed.last_seq + 1
    assert (
        t.closed.frame_count + t.opened.frame_count == u.closed.frame_count + u.opened.frame_count
    )
    assert tracker.current_segment().first_seq == t.boundary_seq
    shared = len(set(t.closed.features) & set(t.opened.features))
    assert shared >= len(set(u.closed.features) & set(u.opened.features))


# -- rule 8: snapshots ---------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(2))
def test_restoring_at_every_frame_keeps_recognition_and_merges(seed: int) -> None:
    rng = np.random.default_rng(seed)
    frames = [
        *stay(rng, A, 30),
        *wide_door(rng, B, A),
        *stay(rng, B, 20),
        *wide_door(rng, A, B),
        *stay(rng, H2, 20),
        *stay(rng, A | H2, 30, p=0.6),
        *stay(rng, A, 20),
    ]
    expected = track(frames)
    tracker = AreaTracker()
    found = []
    for seq, frame in enumerate(frames):
        data = to_bytes(tracker)
        tracker = from_bytes(data)
        assert to_bytes(tracker) == data
        change = tracker.observe(seq, seq * 0.5, frame)
        if change is not None:
            found.append(change)
    assert found == expected[1]
    assert {Rule.SPLIT, Rule.RECOGNISED} <= {change.rule for change in found}
    assert tracker.merged == expected[0].merged != {}
    assert tracker.area_frames == expected[0].area_frames
    assert to_bytes(tracker) == to_bytes(expected[0])


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("blind_frames", -1),
        ("blind_span", -1),
        ("blind_margin", -1),
        ("period_steps", -1),
        ("stay_share", 0.0),
        ("familiar_rate", 0.0),
        ("familiar_rate", 1.5),
        ("familiar_relative", -0.1),
        ("familiar_relative", 1.5),
        ("familiar_margin_frames", -1),
        ("recognise_frames", -1),
        ("recognise_llr", -1.0),
        ("merge_overlap", 0.0),
        ("seam_frames", -1),
    ],
)
def test_invalid_rule_params_are_named(field: str, value: float) -> None:
    with pytest.raises(GraphError, match=field):
        AreaParams(**{field: value})  # type: ignore[arg-type]


# -- rule 9: bounded area models -------------------------------------------------------------

ROOMS = [frozenset(range(1000 * k, 1000 * k + 10)) for k in range(1, 7)]


def tour(rng: np.random.Generator) -> Frames:
    """Six rooms of their own landmarks, room 0 the longest, then back to room 0."""
    frames = stay(rng, ROOMS[0], 60)
    for room in ROOMS[1:]:
        frames += stay(rng, room, 30)
    return frames + stay(rng, ROOMS[0], 30)


@pytest.mark.parametrize("seed", range(3))
def test_the_area_models_stay_bounded_and_forget_the_smallest_areas(seed: int) -> None:
    frames = tour(np.random.default_rng(seed))
    _, free = track(frames, AreaParams(max_area_sightings=0))
    assert moves(free)[-1] == (5, 0)  # unbounded: room 0 is entered again
    bound = 40  # four rooms' worth
    tracker = AreaTracker(AreaParams(max_area_sightings=bound))
    found = []
    for seq, frame in enumerate(frames):
        change = tracker.observe(seq, seq * 0.5, frame)
        found += [change] if change is not None else []
        assert tracker.sightings == sum(map(len, tracker.areas))
        assert tracker.sightings <= bound
        # the state round-trips with the bound (the count of sightings is derived)
        restored = from_bytes(to_bytes(tracker))
        assert restored.sightings == tracker.sightings
        assert to_bytes(restored) == to_bytes(tracker)
    forgotten = [a for a in range(len(tracker.areas)) if not tracker.areas[a]]
    assert forgotten == [1, 2, 3, 4]  # the smallest went first: room 0 has 60 frames, they 30
    assert all(tracker.area_frames[a] == 30 for a in forgotten)  # their frames stay counted
    assert moves(found) == moves(free)  # room 0 was kept, and recognised again
    # a bound that forgets room 0 too: the robot's return opens a new area
    _, forgetful = track(frames, AreaParams(max_area_sightings=30))
    assert moves(forgetful)[:5] == moves(free)[:5]
    assert (forgetful[-1].area, forgetful[-1].revisit_of) == (6, None)


def test_the_bound_changes_nothing_below_it() -> None:
    frames = tour(np.random.default_rng(0))
    _, free = track(frames, AreaParams(max_area_sightings=0))
    _, default = track(frames)
    assert default == free
    assert AreaParams().max_area_sightings >= 100 * sum(map(len, ROOMS))

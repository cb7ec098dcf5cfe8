"""AreaTracker's rules, each pinned on a small hand-made stream that it decides.

Every stream is a few "rooms" of landmark IDs seen with a fixed probability per frame
(seeded). Each test runs the stream with the defaults and with the one rule turned off or
changed, and asserts the difference, so a test fails when its rule stops working.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pytest

from lessmap.core import GraphError, Reason
from lessmap.core.areas.rules import blind_gap, blind_run, missing_frames, seam
from lessmap.core.areas.snapshot import from_bytes, to_bytes
from lessmap.core.areas.tracker import (
    AreaParams,
    AreaReason,
    AreaTracker,
    AreaTransition,
    Rule,
    profile,
    rate_overlap,
)
from lessmap.core.paper.params import PartitionParams
from tests.core.helpers import room_walk

if TYPE_CHECKING:
    from collections.abc import Iterable

    from tests.core.helpers import Frames

A = frozenset(range(10))  # a room; also H1, one half of an open room
B = frozenset(range(100, 110))  # another room behind a door
H2 = frozenset(range(10, 20))  # the other half of the open room


def seen(rng: np.random.Generator, room: Iterable[int], p: float) -> list[int]:
    """The landmarks of ``room`` one frame sees, each with probability ``p``."""
    ids = np.asarray(sorted(room))
    return [int(i) for i in ids[rng.random(ids.size) < p]]


def stay(rng: np.random.Generator, room: Iterable[int], frames: int, p: float = 0.8) -> Frames:
    return [seen(rng, room, p) for _ in range(frames)]


def wide_door(rng: np.random.Generator, into: Iterable[int], left: Iterable[int]) -> Frames:
    """Ten frames in ``into`` that still see ``left`` behind, fading (a 360° sensor)."""
    return [seen(rng, into, 0.8) + seen(rng, left, 0.6 * (1 - k / 10)) for k in range(10)]


def track(
    frames: Frames, params: AreaParams | None = None
) -> tuple[AreaTracker, list[AreaTransition]]:
    tracker = AreaTracker(params)
    found = []
    for seq, frame in enumerate(frames):
        change = tracker.observe(seq, seq * 0.5, frame)
        if change is not None:
            found.append(change)
    return tracker, found


def moves(found: list[AreaTransition]) -> list[tuple[int, int]]:
    return [(change.left_area, change.area) for change in found]


# -- rule 3b: no boundary is seen blind ----------------------------------------------------


@pytest.mark.parametrize("seed", range(3))
def test_a_room_reached_blind_is_no_transition(seed: int) -> None:
    rng = np.random.default_rng(seed)
    frames = [*stay(rng, A, 30), [], [], [], *stay(rng, B, 30)]
    tracker, found = track(frames)
    assert found == []
    assert set(tracker.area_features(0)) == A | B  # one area, both sides
    _, blind_allowed = track(frames, AreaParams(blind_frames=0, blind_span=0))
    assert [c.transition.reason for c in blind_allowed] == [Reason.DISCONNECTED]
    assert [c.reason for c in blind_allowed] == [AreaReason.DISCONNECTED]
    assert 30 <= blind_allowed[0].transition.boundary_seq <= 33
    # the same rooms without the empty frames: a door, and a transition
    rng = np.random.default_rng(seed)
    _, door = track([*stay(rng, A, 30), *stay(rng, B, 30)])
    assert moves(door) == [(0, 1)]


@pytest.mark.parametrize("seed", range(3))
def test_a_room_reached_blind_after_a_glimpse_is_no_transition(seed: int) -> None:
    # Blind for three frames, then two frames of the room left (a wall glimpsed on the way):
    # the boundary follows no empty frame, but a run of blind_span lies within blind_margin
    # non-empty frames before it.
    rng = np.random.default_rng(seed)
    frames = [*stay(rng, A, 30), [], [], [], *stay(rng, A, 2), *stay(rng, B, 30)]
    p = AreaParams()
    assert p.blind_span == 3
    assert p.blind_margin >= 2
    tracker, found = track(frames)
    assert found == []
    assert set(tracker.area_features(0)) == A | B
    _, allowed = track(frames, AreaParams(blind_span=0))
    assert moves(allowed) == [(0, 1)]
    assert allowed[0].transition.boundary_seq == 35  # B's first frame: no empty frame before
    # with no margin the run must reach the boundary: two non-empty frames keep it apart
    _, no_margin = track(frames, AreaParams(blind_margin=0))
    assert moves(no_margin) == [(0, 1)]


OMITTED = AreaParams().for_stream(empty_frames_omitted=True)  # a stream without empty frames
GAP = None  # in a gapped stream: the clock runs on GAP_S seconds with no frame
GAP_S = 5.0


def track_gapped(
    stream: list[list[int] | None], params: AreaParams | None = None, *, restore: bool = False
) -> tuple[AreaTracker, list[AreaTransition]]:
    """Frames every 0.5 s, none in a gap (a stream without empty frames, as MRCLAM's).

    With ``restore``, the tracker goes through a snapshot before every frame.
    """
    tracker = AreaTracker(params)
    found = []
    seq, stamp = 0, 0.0
    for frame in stream:
        if frame is GAP:
            stamp += GAP_S
            continue
        if restore:
            tracker = from_bytes(to_bytes(tracker))
        change = tracker.observe(seq, stamp, frame)
        if change is not None:
            found.append(change)
        seq, stamp = seq + 1, stamp + 0.5
    return tracker, found


@pytest.mark.parametrize("seed", range(3))
def test_a_room_reached_through_a_stamp_gap_is_no_transition(seed: int) -> None:
    # The stream of test_a_room_reached_blind_is_no_transition without its empty frames:
    # the robot's blindness is only in the stamps.
    rng = np.random.default_rng(seed)
    stream = [*stay(rng, A, 30), GAP, *stay(rng, B, 30)]
    assert OMITTED.period_steps  # GAP_S leaves out 9 frames, blind_span is 3
    tracker, found = track_gapped(stream, OMITTED)
    assert found == []
    assert set(tracker.area_features(0)) == A | B
    _, gap_ignored = track_gapped(stream)  # by default stamps are not read
    assert moves(gap_ignored) == [(0, 1)]
    assert gap_ignored[0].transition.boundary_seq == 30  # B's first frame, after the gap
    # a real two-room walk: the same frames at an even pace keep their transition
    _, door = track_gapped([frame for frame in stream if frame is not GAP], OMITTED)
    assert moves(door) == [(0, 1)]


@pytest.mark.parametrize("seed", range(3))
def test_a_stall_at_a_door_keeps_its_transition_when_empty_frames_are_sent(seed: int) -> None:
    # A robot stamped at publish time whose computer stalls at the door for GAP_S: its
    # stream has the same stamp gap as a blind crossing, but it sends its empty frames, so
    # the gap is a stall, not blindness, and the door stays a transition by default. Only
    # a source that declares it leaves out its empty frames gives the gap up to rule 3b.
    rng = np.random.default_rng(seed)
    stream = [*stay(rng, A, 30), [], *stay(rng, A, 3), GAP, *stay(rng, B, 30)]
    _, found = track_gapped(stream)
    assert moves(found) == [(0, 1)]
    assert found[0].transition.boundary_seq == 34  # B's first frame, after the stall
    _, declared = track_gapped(stream, OMITTED)
    assert declared == []


@pytest.mark.parametrize("seed", range(3))
def test_turning_between_two_walls_blind_makes_one_area(seed: int) -> None:
    # MRCLAM's robot 3: two sets of landmarks never seen together, one wall and the other,
    # the robot turning from one to the other seeing nothing for a few seconds.
    rng = np.random.default_rng(seed)
    stream: list[list[int] | None] = []
    for wall in (A, B, A, B, A):
        stream += [GAP, *stay(rng, wall, 60, p=0.3)]
    tracker, found = track_gapped(stream[1:], OMITTED)
    assert found == []
    assert tracker.area_count == 1
    _, gap_ignored = track_gapped(stream[1:])
    assert moves(gap_ignored)[:2] == [(0, 1), (1, 0)]
    assert len(gap_ignored) == 4


@pytest.mark.parametrize("seed", range(3))
def test_a_gap_away_from_the_door_keeps_the_transition(seed: int) -> None:
    # Blind for a while in the middle of room A, then an ordinary door: rule 3b looks only
    # at the boundary's own frames.
    rng = np.random.default_rng(seed)
    stream = [*stay(rng, A, 15), GAP, *stay(rng, A, 15), *stay(rng, B, 30)]
    tracker, found = track_gapped(stream, OMITTED)
    assert moves(found) == [(0, 1)]
    assert tracker.gaps == deque()  # the gap went with the segment it was in
    # restored from a snapshot before every frame: the same decisions and state
    restored, again = track_gapped(stream, OMITTED, restore=True)
    assert again == found
    assert to_bytes(restored) == to_bytes(tracker)


@pytest.mark.parametrize("seed", range(2))
def test_a_gapped_stream_restored_at_every_frame_decides_alike(seed: int) -> None:
    # Sparse sightings: a proposal at the gap waits frames for evidence, across snapshots.
    rng = np.random.default_rng(seed)
    stream: list[list[int] | None] = [*stay(rng, A, 40, p=0.3), GAP]
    stream += [*stay(rng, B, 40, p=0.3), *stay(rng, A, 20), *stay(rng, H2, 30)]
    tracker, found = track_gapped(stream, OMITTED)
    restored, again = track_gapped(stream, OMITTED, restore=True)
    assert again == found
    assert to_bytes(restored) == to_bytes(tracker)
    assert found  # the door to H2, without a gap, is still a transition


def test_missing_frames_are_counted_at_the_median_step() -> None:
    steps = [0.5, 0.5, 0.4, 0.6, 9.0]  # one earlier gap does not move the period
    assert missing_frames(0.6, steps) == 0
    assert missing_frames(1.0, steps) == 1
    assert missing_frames(2.1, steps) == 3
    assert missing_frames(5.0, []) == 0  # no period yet


def test_blind_gap_counts_missing_frames_where_empty_ones_count() -> None:
    frames = [(0, (1,)), (1, (1,)), (2, (1,)), (3, (2,)), (4, (2,))]
    least = (1, 3)  # blind_frames, blind_span
    assert blind_gap(frames, [(3, 1)], 3, least, 0)  # one frame right before the boundary
    assert not blind_gap(frames, [(4, 2)], 3, least, 0)  # two after it: shorter than a span
    assert blind_gap(frames, [(4, 3)], 3, least, 0)  # a span after it
    assert not blind_gap(frames, [(2, 3)], 3, least, 0)  # a span before it, no margin
    assert blind_gap(frames, [(2, 3)], 3, least, 2)  # after frame 1, 2 non-empty frames back
    assert not blind_gap(frames, [(1, 3)], 3, least, 2)  # before frame 1: outside
    assert not blind_gap(frames, [(3, 9)], 3, (0, 0), 2)  # rule 3b off


def test_blind_run_counts_from_the_margin_on() -> None:
    frames = [(0, (1,)), (1, ()), (2, ()), (3, (1,)), (4, (2,)), (5, ()), (6, (2,))]
    assert blind_run(frames, 4, 0) == 1  # frame 5, after the boundary
    assert blind_run(frames, 4, 1) == 1  # from frame 3 on
    assert blind_run(frames, 4, 2) == 2  # from frame 0 on: frames 1, 2
    assert blind_run(frames, 4, 9) == 2  # fewer non-empty frames than the margin: all


# -- rule 3c: a proposal inside the current area is dropped --------------------------------


@pytest.mark.parametrize("seed", range(3))
def test_a_split_into_features_the_area_knows_is_dropped(seed: int) -> None:
    # An open room (A and H2 seen together), a room B, back to the open room's half A,
    # then its other half H2: the proposer splits H2 from A (it forgot H2 when it left for
    # B), but the area has seen H2 in a third of its frames.
    rng = np.random.default_rng(seed)
    frames = [
        *stay(rng, A | H2, 30),
        *stay(rng, B, 30),
        *stay(rng, A, 30),
        *stay(rng, H2, 30),
    ]
    tracker, found = track(frames)
    assert moves(found) == [(0, 1), (1, 0)]
    assert tracker.area_count == 2
    _, without = track(frames, AreaParams(stay_share=2.0))
    assert moves(without) == [(0, 1), (1, 0), (0, 2)]  # H2 taken for a new area
    assert without[-1].transition.boundary_seq == 90


def test_the_doorway_before_a_boundary_is_not_the_area_s_own() -> None:
    # A short first stay whose last three frames see the next room through the door: with
    # those frames counted, B looks familiar to area 0 and the door is missed.
    found, found_without_margin = 0, 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        frames = [
            *stay(rng, A, 12),
            *[seen(rng, A, 0.8) + seen(rng, B, 0.6) for _ in range(3)],
            *stay(rng, B, 30),
        ]
        _, changes = track(frames, AreaParams(seam_frames=0))  # the area boundary reported
        assert moves(changes) == [(0, 1)]
        assert 12 <= changes[0].transition.boundary_seq <= 16
        found += len(changes)
        found_without_margin += len(track(frames, AreaParams(familiar_margin_frames=0))[1])
    assert found == 10
    assert found_without_margin <= 5


def sparse_turning(seed: int, frames: int = 2000, dwell: int = 60) -> Frames:
    """One room of 15 landmarks seen 0-3 at a time by a narrow sensor that turns about.

    Every ``dwell`` frames the sensor faces a new random heading and then sees the
    landmarks within 3 of it: each landmark's rate is low, about 0.1, as in mrclam6.
    """
    rng = np.random.default_rng(seed)
    out: Frames = []
    heading = 0
    for k in range(frames):
        if k % dwell == 0:
            heading = int(rng.integers(0, 15))
        count = int(rng.integers(0, 4))
        out.append(sorted({int((heading + rng.integers(-3, 4)) % 15) for _ in range(count)}))
    return out


def test_a_sparse_sensor_turning_in_one_room_stays_in_it() -> None:
    # The absolute rate alone finds none of the room's features familiar: the proposer's
    # splits at each turn go through; relative to the mean count, they are the room's own.
    with_rule = without_rule = 0
    for seed in range(8):
        frames = sparse_turning(seed)
        with_rule += len(track(frames)[1])
        without_rule += len(track(frames, AreaParams(familiar_relative=0.0))[1])
    assert with_rule == 0
    assert without_rule >= 5


# -- rule 3d: a weak proposal waits until its new side has lasted --------------------------


def doorway(rng: np.random.Generator) -> Frames:
    """Room A, four frames that see room B through the door, then B (from frame 34)."""
    return [
        *stay(rng, A, 30),
        *[seen(rng, A, 0.8) + seen(rng, B, 0.3) for _ in range(4)],
        *stay(rng, B, 30),
    ]


def test_a_weak_proposal_waits_for_its_new_side_to_last() -> None:
    p = AreaParams(seam_frames=0)  # the area boundary reported, not the segments' seam
    early = 0
    for seed in range(10):
        _, found = track(doorway(np.random.default_rng(seed)), p)
        assert moves(found) == [(0, 1)]
        for change in found:
            t = change.transition
            if t.ncut is not None and t.ncut > p.weak_ncut:
                assert t.seq - t.boundary_seq >= p.weak_frames
        _, off = track(doorway(np.random.default_rng(seed)), replace(p, weak_frames=0))
        assert moves(off) == [(0, 1)]
        early += sum(c.transition.seq - c.transition.boundary_seq < p.weak_frames for c in off)
    assert early >= 5  # without the rule, most of these doors are confirmed sooner


def test_a_door_that_stays_in_view_is_found_sooner_than_at_ncut_0_4() -> None:
    # A 360° sensor sees room A from B for ten frames: the door's Ncut falls slowly, and
    # proposals up to the looser bound (held by rule 3d) find it sooner.
    strict = AreaParams(proposal=PartitionParams(ncut_min=0.4, lambda2_min=0.4))
    latency = latency_strict = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        frames = [*stay(rng, A, 30), *wide_door(rng, B, A), *stay(rng, B, 30)]
        (change,) = track(frames)[1]
        (change_strict,) = track(frames, strict)[1]
        assert change.transition.seq <= change_strict.transition.seq
        latency += change.transition.seq - 30
        latency_strict += change_strict.transition.seq - 30
    assert latency < latency_strict - 10


# -- rule 4: a proposal names the area it re-enters ----------------------------------------


@pytest.mark.parametrize("seed", range(3))
def test_proposals_alone_name_revisits(seed: int) -> None:
    walk = room_walk(seed, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    _, found = track(walk.frames, AreaParams(recognise_frames=0))
    assert [0] + [change.area for change in found] == [0, 1, 2, 3, 2, 1, 0]
    assert {change.rule for change in found} == {Rule.SPLIT}
    assert [change.revisit_of for change in found] == [None, None, None, 2, 1, 0]


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

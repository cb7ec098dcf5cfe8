"""AreaTracker rule 3b: no boundary is seen blind (empty frames, stamp gaps, their counts)."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from lessmap.core import Reason
from lessmap.core.areas.rules import blind_gap, blind_run, missing_frames
from lessmap.core.areas.snapshot import from_bytes, to_bytes
from lessmap.core.areas.tracker import AreaParams, AreaReason, AreaTracker, AreaTransition
from tests.core.areas_rules_helpers import H2, A, B, moves, stay, track

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

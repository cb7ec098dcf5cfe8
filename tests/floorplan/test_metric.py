from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lessmap.floorplan.grid import room_labels
from lessmap.floorplan.metric import Cut, StreamScore, Track, precision_recall, stream_score

FLOORPLANS = Path(__file__).resolve().parents[2] / ".." / "shared" / "floorplans"


def strip(*spans: tuple[int, int]) -> np.ndarray:
    """A 1 x 30 label row: span i (start, stop) gets label i + 1."""
    row = np.zeros((1, 30), dtype=np.int32)
    for label, (start, stop) in enumerate(spans, start=1):
        row[0, start:stop] = label
    return row


def test_two_rooms_three_segments_by_hand() -> None:
    rooms = strip((0, 10), (10, 30))  # 10 and 20 cells
    segments = strip((0, 15), (15, 25), (25, 30))  # 15 (10 + 5), 10 and 5 cells
    score = precision_recall(segments, rooms, min_pixels=0)
    assert score.recall == pytest.approx((10 / 10 + 10 / 20) / 2)
    assert score.precision == pytest.approx((10 / 15 + 10 / 10 + 5 / 5) / 3)
    assert score.recall_pixels == pytest.approx((10 + 10) / 30)
    assert score.precision_pixels == pytest.approx((10 + 10 + 5) / 30)
    assert (score.rooms, score.segments) == (2, 3)


def test_label_values_do_not_matter() -> None:
    rooms = strip((0, 10), (10, 30))
    segments = strip((0, 15), (15, 25), (25, 30))
    relabelled = np.choose(segments, [0, 70, 3, 12])
    assert precision_recall(relabelled, rooms * 9, min_pixels=0) == precision_recall(
        segments, rooms, min_pixels=0
    )


def test_unlabelled_cells_are_ignored_but_a_segment_outside_rooms_counts_its_area() -> None:
    rooms = strip((0, 10), (12, 30))  # cells 10-11: a door line, in no room
    segments = strip((0, 12), (12, 30))
    segments[0, 25:] = 0  # not labelled: out of the segment
    score = precision_recall(segments, rooms, min_pixels=0)
    assert score.precision == pytest.approx((10 / 12 + 13 / 13) / 2)
    assert score.recall == pytest.approx((10 / 10 + 13 / 18) / 2)


def test_rooms_and_segments_of_100_cells_or_fewer_are_dropped() -> None:
    rooms = np.zeros((10, 30), dtype=np.int32)
    rooms[:, :10] = 1  # exactly 100 cells: dropped, as the benchmark drops them
    rooms[:, 10:] = 2  # 200 cells
    segments = np.ones_like(rooms)  # one segment of 300 cells
    score = precision_recall(segments, rooms)
    assert score.rooms == 1
    assert score.recall == 1.0
    assert score.precision == pytest.approx(200 / 300)


def test_no_segment_gives_nan_precision_and_zero_recall() -> None:
    rooms = strip((0, 10), (10, 30))
    score = precision_recall(np.zeros_like(rooms), rooms, min_pixels=0)
    assert math.isnan(score.precision)
    assert score.recall == 0.0


def test_shapes_must_match() -> None:
    with pytest.raises(ValueError, match="shape"):
        precision_recall(np.zeros((2, 3), dtype=int), np.zeros((3, 2), dtype=int))


def test_the_ground_truth_scores_itself_perfectly_on_a_benchmark_map() -> None:
    gt = FLOORPLANS / "office_a_gt_segmentation.png"
    if not gt.exists():
        pytest.skip("../shared/floorplans not found (not in this checkout)")
    rooms = room_labels(gt, min_room_m2=0.0)
    score = precision_recall(rooms, rooms)
    assert (score.precision, score.recall) == (1.0, 1.0)
    merged = precision_recall(np.where(rooms > 0, 1, 0), rooms)  # every room one segment
    assert merged.recall == 1.0
    assert merged.precision < 0.5


# A robot walks 0.5 m a frame: room 0 (frames 0-9, x 0-4.5), room 1 (10-19, x 5-9.5), then
# back into room 0 (20-29, x 4.5 down to 0). True changes: frame 10 (x 5), frame 20 (x 4.5).
def walk() -> Track:
    x = np.concatenate([0.5 * np.arange(20), 4.5 - 0.5 * np.arange(10)])
    rooms = np.array([0] * 10 + [1] * 10 + [0] * 10)
    return Track(np.arange(30), np.stack([x, np.zeros(30)], axis=1), rooms)


CUTS = [
    Cut(seq=12, boundary_seq=10, area=1, revisit=False),  # decided 1 m into room 1
    Cut(seq=15, boundary_seq=15, area=2, revisit=False),  # spurious, mid-room 1
    Cut(seq=22, boundary_seq=21, area=0, revisit=True),  # back in room 0, named as before
]


def test_stream_scores_by_hand() -> None:
    score = stream_score(walk(), CUTS, tolerance_m=1.0)
    figures = score.figures()
    assert (score.changes, score.transitions) == (2, 3)
    assert figures["boundary_recall"] == 1.0  # 0 m and 0.5 m away
    assert figures["boundary_precision"] == pytest.approx(2 / 3)
    assert figures["decision_recall"] == 1.0  # both exactly 1 m away
    assert figures["decision_precision"] == pytest.approx(2 / 3)
    assert figures["decision_lag_m"] == 1.0
    # segments: 0-9 (room 0), 10-14 (1), 15-20 (1 x5, 0 x1), 21-29 (0)
    assert figures["purity"] == pytest.approx(29 / 30)
    # visits: 0-9 all in segment 0; 10-19 split 5/5 (tie: 5 covered); 20-29: 9 in segment 3
    assert figures["coverage"] == pytest.approx(24 / 30)
    assert figures["revisit_accuracy"] == 1.0
    path_m = 9.5 + 5.0 + 4.5
    assert score.path_m == pytest.approx(path_m)
    assert figures["transitions_per_100m"] == pytest.approx(300 / path_m)
    assert figures["changes_per_100m"] == pytest.approx(200 / path_m)


def test_a_tighter_tolerance_misses_the_late_decisions() -> None:
    figures = stream_score(walk(), CUTS, tolerance_m=0.9).figures()
    assert figures["decision_recall"] == 0.0
    assert figures["boundary_recall"] == 1.0


def test_a_transition_pairs_with_the_change_it_is_nearest_in_time() -> None:
    # room 0 (x 0-4.5), room 1 (x 5-9.5 and back to 5), room 0 again (x 4.5-0): the door
    # is passed at frames 10 and 30; a boundary at frame 29 (x 5) is 0 m from the first
    # change's place but 0.5 m of walk from the second's: it is the second's
    x = np.concatenate([0.5 * np.arange(20), 9.5 - 0.5 * np.arange(10), 4.5 - 0.5 * np.arange(10)])
    track = Track(
        np.arange(40), np.stack([x, np.zeros(40)], axis=1), np.array([0] * 10 + [1] * 20 + [0] * 10)
    )
    score = stream_score(track, [Cut(29, 29, 0, revisit=False)], tolerance_m=1.0)
    assert score.boundary_matched == 1
    assert score.lags_m == (-0.5,)  # decided half a metre before the second change


def test_a_wrong_revisit_is_counted_wrong() -> None:
    cuts = [Cut(12, 10, 1, revisit=False), Cut(22, 21, 1, revisit=True)]  # room 0 named 1
    assert stream_score(walk(), cuts).figures()["revisit_accuracy"] == 0.0


def test_scores_pool_by_adding_counts() -> None:
    one = stream_score(walk(), CUTS)
    both = one + StreamScore() + one
    assert both.changes == 4
    assert both.lags_m == (1.0, 1.0, 1.0, 1.0)
    assert both.figures()["purity"] == one.figures()["purity"]
    assert StreamScore().figures()["purity"] is None

"""Baseline segmentations: fixed features, fixed frames, no partition."""

from __future__ import annotations

import pytest

from lessmap.evaluation.baselines import fixed_features, fixed_frames, single_submap
from lessmap.evaluation.data.segmentation import submap_features, submap_stats


def new_features_stream(frames: int, per_frame: int) -> list[list[int]]:
    """Every frame sees ``per_frame`` features never seen before."""
    return [list(range(k * per_frame, (k + 1) * per_frame)) for k in range(frames)]


@pytest.mark.parametrize(("limit", "expected"), [(50, 10), (60, 9), (5, 100), (1000, 1)])
def test_fixed_features_counts_on_new_features(limit: int, expected: int) -> None:
    frames = new_features_stream(100, 5)  # 500 features
    labels = fixed_features(frames, limit)
    assert int(labels.max()) + 1 == expected
    sizes = [len(f) for f in submap_features(frames, labels)]
    assert all(size >= limit for size in sizes[:-1])
    assert all(size < limit + 5 for size in sizes)


def test_fixed_features_counts_reobserved_features_again() -> None:
    # Features 0..9 cycle: each submap of 4 features re-sees what earlier submaps held.
    frames = [[k % 10, (k + 1) % 10] for k in range(30)]
    labels = fixed_features(frames, 4)
    assert labels.tolist() == [
        0,
        0,
        0,
        1,
        1,
        1,
        2,
        2,
        2,
        3,
        3,
        3,
        4,
        4,
        4,
        5,
        5,
        5,
        6,
        6,
        6,
        7,
        7,
        7,
        8,
        8,
        8,
        9,
        9,
        9,
    ]


def test_fixed_features_keeps_empty_frames_in_the_open_submap() -> None:
    frames: list[list[int]] = [[1, 2], [], [3], [], [4, 5]]
    assert fixed_features(frames, 3).tolist() == [0, 0, 0, 1, 1]


def test_fixed_frames_and_single_submap() -> None:
    frames = new_features_stream(100, 2)
    assert int(fixed_frames(frames, 30).max()) + 1 == 4
    assert fixed_frames(frames, 30).tolist()[29:31] == [0, 1]
    assert set(single_submap(frames).tolist()) == {0}
    stats = submap_stats(frames, fixed_frames(frames, 30))
    assert (stats.submaps, stats.features_min, stats.features_max) == (4, 20, 60)
    assert stats.features_mean == pytest.approx(50.0)
    assert stats.frames_mean == pytest.approx(25.0)


@pytest.mark.parametrize("size", [0, -3])
def test_sizes_must_be_positive(size: int) -> None:
    with pytest.raises(ValueError, match="needs"):
        fixed_features([[1]], size)
    with pytest.raises(ValueError, match="needs"):
        fixed_frames([[1]], size)

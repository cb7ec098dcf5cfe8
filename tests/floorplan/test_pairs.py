from __future__ import annotations

import numpy as np
import pytest

from lessmap.floorplan.pairs import unique_pairs


@pytest.mark.parametrize("seed", range(20))
def test_unique_pairs_equal_numpys_rows(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 2000))
    low = int(rng.integers(-50, 50))
    a = rng.integers(low, low + int(rng.integers(1, 40)), size=n)
    b = rng.integers(low, low + int(rng.integers(1, 400)), size=n)
    rows, counts, inverse = unique_pairs(a, b)
    want, want_inverse, want_counts = np.unique(
        np.stack([a, b], axis=1), axis=0, return_inverse=True, return_counts=True
    )
    assert np.array_equal(rows, want)
    assert np.array_equal(counts, want_counts)
    assert np.array_equal(inverse, want_inverse.ravel())
    assert np.array_equal(rows[inverse], np.stack([a, b], axis=1))


def test_labels_too_far_apart_for_one_key_take_the_slow_way() -> None:
    a = np.array([0, 2**40, 0, 2**40], dtype=np.int64)
    b = np.array([2**40, -(2**40), 2**40, 3], dtype=np.int64)
    rows, counts, inverse = unique_pairs(a, b)
    assert rows.tolist() == [[0, 2**40], [2**40, -(2**40)], [2**40, 3]]
    assert counts.tolist() == [2, 1, 1]
    assert inverse.tolist() == [0, 1, 0, 2]


def test_no_pairs_and_mismatched_lengths() -> None:
    rows, counts, inverse = unique_pairs([], [])
    assert rows.shape == (0, 2)
    assert counts.size == 0
    assert inverse.size == 0
    with pytest.raises(ValueError, match="3 first labels for 2 second"):
        unique_pairs([1, 2, 3], [1, 2])

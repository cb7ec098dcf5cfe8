"""The lag profile: running then exponential means, its ceiling and the lag it falls at."""

from __future__ import annotations

import numpy as np
import pytest

from lessmap.core import lagprofile


def profile(rows: list[list[float]], smoothing: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    mean, seen = np.zeros(4), np.zeros(4, dtype=np.int64)
    for row in rows:
        lagprofile.learn(mean, seen, np.array(row), smoothing)
    return mean, seen


def test_early_rows_are_averaged_then_weighed_by_the_smoothing() -> None:
    mean, seen = profile([[1.0, 0.5], [0.0]])
    assert seen.tolist() == [2, 1, 0, 0]
    assert mean[:2].tolist() == [0.5, 0.5]  # (1 + 0) / 2: a running mean at first
    mean, _ = profile([[1.0], [1.0], [1.0], [0.0]], smoothing=0.5)
    assert mean[0] == pytest.approx(0.5)  # the 4th row weighs max(1/4, 0.5)


def test_the_ceiling_is_the_profile_taken_back_to_lag_zero() -> None:
    mean, seen = profile([[0.9, 0.8, 0.7]])
    assert lagprofile.ceiling(mean, seen) == pytest.approx(1.0)  # 2 * 0.9 - 0.8
    mean, seen = profile([[0.7, 0.65]])
    assert lagprofile.ceiling(mean, seen) == pytest.approx(0.75)
    assert lagprofile.ceiling(*profile([])) == 1.0  # nothing learnt
    assert lagprofile.ceiling(*profile([[0.6]])) == pytest.approx(0.6)  # one lag: itself


def test_the_first_lag_at_the_bar_or_none_until_known() -> None:
    mean, seen = profile([[0.9, 0.8]])
    assert lagprofile.first_lag_at(mean, seen, 0.5, 1, 4) is None  # lags 3, 4 unknown
    mean, seen = profile([[0.9, 0.8, 0.6, 0.4]])
    assert lagprofile.first_lag_at(mean, seen, 0.6, 1, 4) == 3
    assert lagprofile.first_lag_at(mean, seen, 0.95, 2, 4) == 2  # never before `least`
    assert lagprofile.first_lag_at(mean, seen, 0.1, 1, 4) == 4  # all known, none fell

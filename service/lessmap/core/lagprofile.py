"""How fast a stream's view changes: the mean CovRate of frames 1, 2, 3… apart.

Frame counts mean different distances at different rates, speeds and ranges; the lag
profile turns them into a unit of the stream's own: the frames over which the view keeps a
share of what two frames seen from one place share. ``rooms`` sizes its window by it,
``areas`` its spans (``AreaParams.spans_in_views``). In-place updates of two arrays, so the
owners' snapshots hold them as they are.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def learn(
    lag_mean: NDArray[np.float64],
    lag_seen: NDArray[np.int64],
    row: NDArray[np.float64],
    smoothing: float,
) -> None:
    """Take one frame's similarities to the frames 1..len(row) before it."""
    lags = len(row)
    if not lags:
        return
    seen = lag_seen[:lags] + 1
    # a running mean at first, then an exponential one: early frames teach fast
    weight = np.maximum(1.0 / seen, smoothing)
    lag_mean[:lags] += weight * (row - lag_mean[:lags])
    lag_seen[:lags] = seen


def ceiling(lag_mean: NDArray[np.float64], lag_seen: NDArray[np.int64]) -> float:
    """The CovRate of two frames seen from one place: the profile taken back to lag 0.

    Missed detections and misassociations keep it under 1; from the first two lags, so
    the robot's motion between neighbouring frames is taken out.
    """
    if not lag_seen[0]:
        return 1.0
    first = float(lag_mean[0])
    back = 2.0 * first - float(lag_mean[1]) if lag_seen[1] else first
    return min(1.0, max(first, back))


def first_lag_at(
    lag_mean: NDArray[np.float64], lag_seen: NDArray[np.int64], bar: float, least: int, most: int
) -> int | None:
    """The first lag from ``least`` whose similarity fell to ``bar``; ``most`` if none did.

    None while the profile knows neither such a lag nor every lag up to ``most``.
    """
    known = min(int(np.count_nonzero(lag_seen)), most)
    for d in range(least, known + 1):
        if lag_mean[d - 1] <= bar:
            return d
    return most if known >= most else None

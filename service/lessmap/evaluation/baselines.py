"""Baseline segmentations the paper compares against (§4.1, Figs. 9-10).

Each returns the frame → submap labels (see ``lessmap.evaluation.data.segmentation``), computed
from the frames alone, in one pass, as an online mapper would.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Collection, Sequence

    from numpy.typing import NDArray


def fixed_features(frames: Sequence[Collection[int]], limit: int) -> NDArray[np.int64]:
    """Close a submap once it holds ``limit`` distinct features (Estrada et al. 2005).

    The features of a submap are those observed in its frames; a feature seen again after a
    split counts again in the new submap, as a local map re-initializes what it re-observes.
    The frame that reaches the limit stays in the submap; the next frame opens a new one, so
    a submap holds at least ``limit`` features (up to ``limit`` + one frame's worth), except
    the last.

    Args:
        frames: the feature IDs of each frame, in order.
        limit: features per submap, >= 1 (the paper's baseline uses 50 and 60).
    """
    if limit < 1:
        msg = f"fixed_features needs limit >= 1, got {limit}"
        raise ValueError(msg)
    labels = np.zeros(len(frames), dtype=np.int64)
    current: set[int] = set()
    label = 0
    for index, features in enumerate(frames):
        if len(current) >= limit:
            label += 1
            current = set()
        labels[index] = label
        current.update(features)
    return labels


def fixed_frames(frames: Sequence[Collection[int]], length: int) -> NDArray[np.int64]:
    """Cut the frames into submaps of ``length`` consecutive frames (the last may be shorter).

    Args:
        frames: the feature IDs of each frame, in order.
        length: frames per submap, >= 1.
    """
    if length < 1:
        msg = f"fixed_frames needs length >= 1, got {length}"
        raise ValueError(msg)
    labels: NDArray[np.int64] = np.arange(len(frames), dtype=np.int64) // length
    return labels


def single_submap(frames: Sequence[Collection[int]]) -> NDArray[np.int64]:
    """Return the no-partition baseline: every frame in submap 0 (e = 0 by construction)."""
    return np.zeros(len(frames), dtype=np.int64)

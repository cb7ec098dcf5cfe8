"""Rule 7's bookkeeping: sightings move between areas, and merged areas pool theirs.

``areas[a]`` counts, per feature, the non-empty frames of area ``a`` that saw it;
``area_frames[a]`` counts those frames. A merged area keeps its slot, empty, and its entry
in ``merged`` (its id -> the area it went into), so ids are never reused.
"""

from __future__ import annotations


def move(
    areas: list[dict[int, int]],
    area_frames: list[int],
    left: int,
    area: int,
    after: dict[int, int],
    nonempty: int,
) -> None:
    """Move the sightings ``after`` of ``nonempty`` frames from area ``left`` to ``area``."""
    left_counts, area_counts = areas[left], areas[area]
    for feature, n in after.items():
        remaining = left_counts.get(feature, 0) - n
        if remaining > 0:
            left_counts[feature] = remaining
        else:
            left_counts.pop(feature, None)
        area_counts[feature] = area_counts.get(feature, 0) + n
    area_frames[left] -= nonempty
    area_frames[area] += nonempty


def merge(
    areas: list[dict[int, int]], area_frames: list[int], merged: dict[int, int], a: int, b: int
) -> int:
    """Merge areas ``a`` and ``b``, the later id into the earlier; return the earlier."""
    keep, gone = min(a, b), max(a, b)
    into = areas[keep]
    for feature, n in areas[gone].items():
        into[feature] = into.get(feature, 0) + n
    areas[gone] = {}
    area_frames[keep] += area_frames[gone]
    area_frames[gone] = 0
    merged[gone] = keep
    return keep

"""Scores of a room segmentation: the benchmark's room-map precision/recall and stream scores.

``precision_recall``: ipa_room_segmentation's ``computePrecisionRecall`` (Bormann et al., ICRA
2016). Label 0 is ignored; rooms and segments of <= 100 cells dropped; recall = mean over rooms
of largest overlap with one segment / room cells; precision = mean over segments of largest
overlap with one room / segment cells (a segment's cells outside every room count).

``stream_score``, per robot (a true change: the first frame in another room, at its position):
boundary (decision) recall / precision: changes / transitions paired one-to-one with a
boundary (decision) frame within ``tolerance_m``, between the change's neighbouring changes,
most pairs then least path walked; lag: path walked from change to paired decision (median);
purity: frames whose segment's most common room is theirs; coverage: frames in their visit's
most common segment; revisit accuracy: named revisits whose segment's most common room is the
named area's earlier one; transitions (true changes) per 100 m walked.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linear_sum_assignment

from lessmap.floorplan.pairs import unique_pairs

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

__all__ = ["Cut", "PrecisionRecall", "StreamScore", "Track", "precision_recall", "stream_score"]

#: The benchmark drops rooms and segments of this many pixels or fewer.
MIN_PIXELS = 100


@dataclass(frozen=True, slots=True, kw_only=True)
class PrecisionRecall:
    """The benchmark's figures for one room map (module docstring)."""

    precision: float  # mean over segments; nan without a segment
    recall: float  # mean over rooms; nan without a room
    precision_pixels: float  # pooled over segments
    recall_pixels: float
    rooms: int
    segments: int


def _sized(
    labels: NDArray[np.int64], min_pixels: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The labels kept (more than ``min_pixels`` cells, not 0) and their sizes."""
    ids, sizes = np.unique(labels[labels != 0], return_counts=True)
    keep = sizes > min_pixels
    return ids[keep], sizes[keep]


def precision_recall(
    segmentation: NDArray[np.integer],
    ground_truth: NDArray[np.integer],
    min_pixels: int = MIN_PIXELS,
) -> PrecisionRecall:
    """Score a room map against ground-truth rooms (int label arrays of one shape, 0 = none)."""
    seg = np.asarray(segmentation, dtype=np.int64)
    gt = np.asarray(ground_truth, dtype=np.int64)
    if seg.shape != gt.shape:
        msg = f"segmentation {seg.shape} and ground truth {gt.shape} differ in shape"
        raise ValueError(msg)
    rooms, room_sizes = _sized(gt, min_pixels)
    segments, segment_sizes = _sized(seg, min_pixels)
    overlap = np.zeros((segments.size, rooms.size))
    both = np.isin(seg, segments) & np.isin(gt, rooms)
    if both.any():
        unique, counts, _ = unique_pairs(seg[both], gt[both])
        rows = np.searchsorted(segments, unique[:, 0])
        cols = np.searchsorted(rooms, unique[:, 1])
        overlap[rows, cols] = counts
    best_room = overlap.max(axis=1) if rooms.size else np.zeros(segments.size)
    best_segment = overlap.max(axis=0) if segments.size else np.zeros(rooms.size)
    nan = float("nan")
    return PrecisionRecall(
        precision=float(np.mean(best_room / segment_sizes)) if segments.size else nan,
        recall=float(np.mean(best_segment / room_sizes)) if rooms.size else nan,
        precision_pixels=float(best_room.sum() / segment_sizes.sum()) if segments.size else nan,
        recall_pixels=float(best_segment.sum() / room_sizes.sum()) if rooms.size else nan,
        rooms=int(rooms.size),
        segments=int(segments.size),
    )


@dataclass(frozen=True, slots=True)
class Track:
    """One robot's frames in seq order: seq, true position (m) and true room."""

    seqs: NDArray[np.int64]  # (n,), increasing
    xy: NDArray[np.float64]  # (n, 2)
    rooms: NDArray[np.int64]  # (n,)


@dataclass(frozen=True, slots=True)
class Cut:
    """A transition as the stream scores need it."""

    seq: int  # decision frame
    boundary_seq: int  # first frame of the new segment
    area: int  # the area entered
    revisit: bool  # the method named an area it had seen before


@dataclass(frozen=True, slots=True, kw_only=True)
class StreamScore:
    """Counts behind the stream scores; ``+`` pools robots and runs."""

    changes: int = 0
    transitions: int = 0
    boundary_matched: int = 0
    decision_matched: int = 0
    frames: int = 0
    pure_frames: int = 0
    covered_frames: int = 0
    revisits: int = 0
    revisits_right: int = 0
    path_m: float = 0.0
    lags_m: tuple[float, ...] = field(default=())

    def __add__(self, other: StreamScore) -> StreamScore:
        """Pool two scores."""
        return StreamScore(
            changes=self.changes + other.changes,
            transitions=self.transitions + other.transitions,
            boundary_matched=self.boundary_matched + other.boundary_matched,
            decision_matched=self.decision_matched + other.decision_matched,
            frames=self.frames + other.frames,
            pure_frames=self.pure_frames + other.pure_frames,
            covered_frames=self.covered_frames + other.covered_frames,
            revisits=self.revisits + other.revisits,
            revisits_right=self.revisits_right + other.revisits_right,
            path_m=self.path_m + other.path_m,
            lags_m=self.lags_m + other.lags_m,
        )

    def figures(self) -> dict[str, float | None]:
        """The ratios (None where a denominator is 0)."""

        def ratio(part: float, whole: float) -> float | None:
            return part / whole if whole else None

        return {
            "boundary_recall": ratio(self.boundary_matched, self.changes),
            "boundary_precision": ratio(self.boundary_matched, self.transitions),
            "decision_recall": ratio(self.decision_matched, self.changes),
            "decision_precision": ratio(self.decision_matched, self.transitions),
            "decision_lag_m": statistics.median(self.lags_m) if self.lags_m else None,
            "purity": ratio(self.pure_frames, self.frames),
            "coverage": ratio(self.covered_frames, self.frames),
            "revisit_accuracy": ratio(self.revisits_right, self.revisits),
            "transitions_per_100m": ratio(100.0 * self.transitions, self.path_m),
            "changes_per_100m": ratio(100.0 * self.changes, self.path_m),
        }


def _match(
    changes: NDArray[np.int64],
    found: NDArray[np.int64],
    xy: NDArray[np.float64],
    walked: NDArray[np.float64],
    tol_m: float,
) -> list[tuple[int, int]]:
    """Pair true changes with transitions one-to-one (indices into ``changes``, ``found``).

    A pair lies within ``tol_m``, the transition between the change's neighbouring
    changes; the most pairs, then the least path walked between paired frames.
    """
    if changes.size == 0 or found.size == 0:
        return []
    distance = np.linalg.norm(xy[changes][:, None, :] - xy[found][None, :, :], axis=2)
    before = np.concatenate([[-1], changes[:-1]])
    after = np.concatenate([changes[1:], [np.iinfo(np.int64).max]])
    allowed = (
        (distance <= tol_m) & (found[None, :] > before[:, None]) & (found[None, :] < after[:, None])
    )
    apart_m = np.abs(walked[changes][:, None] - walked[found][None, :])
    # a forbidden pair costs more than all allowed pairs together: the most pairs first
    forbidden = 1.0 + apart_m[allowed].sum() if allowed.any() else 1.0
    rows, cols = linear_sum_assignment(np.where(allowed, apart_m, forbidden))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if allowed[r, c]]


def _majority_share(groups: NDArray[np.int64], values: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per element, whether its value is its group's most common one (ties: the smaller)."""
    unique, counts, inverse = unique_pairs(groups, values)
    order = np.lexsort((unique[:, 1], -counts, unique[:, 0]))
    first = np.unique(unique[order, 0], return_index=True)[1]
    best = unique[order][first]  # per group, in group order
    wins = unique[:, 1] == best[np.searchsorted(best[:, 0], unique[:, 0]), 1]
    out: NDArray[np.bool_] = wins[inverse.reshape(-1)]
    return out


def stream_score(
    track: Track, cuts: Sequence[Cut], tolerance_m: float = 1.0, first_area: int = 0
) -> StreamScore:
    """Score one robot's transitions against its true rooms (definitions: module docstring).

    Args:
        track: the robot's frames.
        cuts: its transitions, in decision order.
        tolerance_m: how near a true change a matched transition lies.
        first_area: the area of the frames before the first transition.
    """
    n = track.seqs.size
    if n == 0:
        return StreamScore()
    rooms = np.asarray(track.rooms, dtype=np.int64)
    xy = np.asarray(track.xy, dtype=np.float64)
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    walked = np.concatenate([[0.0], np.cumsum(steps)])
    changes = np.flatnonzero(rooms[1:] != rooms[:-1]) + 1

    def frame_of(seqs: list[int]) -> NDArray[np.int64]:
        index = np.searchsorted(track.seqs, np.asarray(seqs, dtype=np.int64))
        return np.clip(index, 0, n - 1).astype(np.int64)

    decision = frame_of([c.seq for c in cuts])
    boundary = frame_of([c.boundary_seq for c in cuts])
    boundary_pairs = _match(changes, boundary, xy, walked, tolerance_m)
    decision_pairs = _match(changes, decision, xy, walked, tolerance_m)
    lags = tuple(float(walked[decision[d]] - walked[changes[c]]) for c, d in decision_pairs)
    # segments and areas per frame, from the boundaries in frame order
    order = np.argsort(boundary, kind="stable")
    segment = np.searchsorted(boundary[order], np.arange(n), side="right")
    areas = np.concatenate([[first_area], [cuts[i].area for i in order]]).astype(np.int64)
    area = areas[segment]
    visit = np.concatenate([[0], np.cumsum(rooms[1:] != rooms[:-1])])
    pure = _majority_share(segment, rooms)
    covered = _majority_share(visit, segment)
    revisits = right = 0
    for rank, i in enumerate(order):
        if not cuts[i].revisit:
            continue
        revisits += 1
        mine = segment == rank + 1
        earlier = (area == cuts[i].area) & (np.arange(n) < boundary[i])
        if mine.any() and earlier.any():
            right += _mode(rooms[mine]) == _mode(rooms[earlier])
    return StreamScore(
        changes=int(changes.size),
        transitions=len(cuts),
        boundary_matched=len(boundary_pairs),
        decision_matched=len(decision_pairs),
        frames=n,
        pure_frames=int(pure.sum()),
        covered_frames=int(covered.sum()),
        revisits=revisits,
        revisits_right=right,
        path_m=float(walked[-1]),
        lags_m=lags,
    )


def _mode(values: NDArray[np.int64]) -> int:
    """The most common value (the smaller on ties)."""
    ids, counts = np.unique(values, return_counts=True)
    return int(ids[np.argmax(counts)])

"""Segmentations as frame → submap labels: the LESS-mapping run and submap statistics.

A segmentation of a robot's frames is an int array ``labels`` aligned with the frames (file
order): ``labels[k]`` is the submap of frame k. Submap ids are consecutive from 0 in order of
their first frame, whatever method produced them.

For LESS-mapping, each transition opens a submap at its ``boundary_seq`` (the estimated first
frame in the new area), so frame k belongs to the last submap opened at or before its seq.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core import Evaluation, Partitioner, PartitionParams, Transition

if TYPE_CHECKING:
    from collections.abc import Collection, Sequence

    from numpy.typing import NDArray

    from lessmap.files.frames import FrameRow


@dataclass(frozen=True, slots=True, kw_only=True)
class LessmapRun:
    """One partitioner run over a robot's frames."""

    params: PartitionParams
    labels: NDArray[np.int64]  # (frames,) submap of each frame
    transitions: tuple[Transition, ...]
    evaluations: tuple[Evaluation, ...]  # one per decision that computed figures, in order


@dataclass(frozen=True, slots=True, kw_only=True)
class SubmapStats:
    """Size of the submaps of a segmentation (features = distinct landmarks observed)."""

    submaps: int
    features_mean: float
    features_min: int
    features_max: int
    frames_mean: float

    def as_dict(self) -> dict[str, float | int]:
        """Return the figures as JSON-ready values."""
        return {
            "submaps": self.submaps,
            "features_mean": round(self.features_mean, 2),
            "features_min": self.features_min,
            "features_max": self.features_max,
            "frames_mean": round(self.frames_mean, 2),
        }


def consecutive(labels: Sequence[int] | NDArray[np.int64]) -> NDArray[np.int64]:
    """Renumber labels 0, 1, ... in order of first appearance."""
    raw = np.asarray(labels, dtype=np.int64)
    if raw.size == 0:
        return raw
    _, first, inverse = np.unique(raw, return_index=True, return_inverse=True)
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    result: NDArray[np.int64] = rank[inverse]
    return result


def labels_from_transitions(
    seqs: Sequence[int] | NDArray[np.int64], transitions: Sequence[Transition]
) -> NDArray[np.int64]:
    """Label frames by the submaps the transitions opened (frames in seq order).

    Frame k belongs to the submap opened by the last transition whose ``boundary_seq`` is
    at or before ``seqs[k]``, or to the first submap before any.
    """
    starts = np.sort(np.asarray([t.opened.first_seq for t in transitions], dtype=np.int64))
    raw = np.searchsorted(starts, np.asarray(seqs, dtype=np.int64), side="right")
    return consecutive(raw.astype(np.int64))


def run_lessmap(frames: Sequence[FrameRow], params: PartitionParams) -> LessmapRun:
    """Run one partitioner over the frames (one robot), deciding at every frame.

    Every decision is solved in full, so the evaluations carry Ncut and λ2 for plots.
    """
    partitioner = Partitioner(params, always_solve=True)
    transitions: list[Transition] = []
    evaluations: list[Evaluation] = []
    for frame in frames:
        transition = partitioner.observe(frame.seq, frame.stamp_s, frame.features)
        if transition is not None:
            transitions.append(transition)
        evaluation = partitioner.last_evaluation
        if evaluation is not None and evaluation.seq == frame.seq:
            evaluations.append(evaluation)  # a decision was made at this very frame
    labels = labels_from_transitions([frame.seq for frame in frames], transitions)
    return LessmapRun(
        params=params,
        labels=labels,
        transitions=tuple(transitions),
        evaluations=tuple(evaluations),
    )


def submap_features(
    frames: Sequence[Collection[int]], labels: Sequence[int] | NDArray[np.int64]
) -> list[set[int]]:
    """Return the distinct features observed in each submap, by submap id."""
    count = int(np.max(labels)) + 1 if len(labels) else 0
    features: list[set[int]] = [set() for _ in range(count)]
    for frame, label in zip(frames, labels, strict=True):
        features[int(label)].update(frame)
    return features


def submap_stats(
    frames: Sequence[Collection[int]], labels: Sequence[int] | NDArray[np.int64]
) -> SubmapStats:
    """Return the submap count and sizes of a segmentation (labels from ``consecutive``)."""
    sizes = [len(f) for f in submap_features(frames, labels)]
    frame_counts = np.bincount(np.asarray(labels, dtype=np.int64), minlength=1)
    return SubmapStats(
        submaps=len(sizes),
        features_mean=float(np.mean(sizes)) if sizes else 0.0,
        features_min=min(sizes, default=0),
        features_max=max(sizes, default=0),
        frames_mean=float(np.mean(frame_counts)) if len(labels) else 0.0,
    )

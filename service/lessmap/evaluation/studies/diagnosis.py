"""Why e comes out as it does: stream statistics, parameter variants, equal-count baselines.

Every figure here answers one question of the results page (docs/RESULTS.md):

- ``stream_stats``: how dense the feature stream is (features per frame, how long a feature
  stays in view). LESS-mapping's CovGraph inherits its shape from these.
- ``variant_row``: one LESS-mapping run (a parameter variant) with e under both membership
  rules, why each transition was declared, the submap sizes, how many landmarks consecutive
  submaps share, and the baselines cut to the same number of submaps — e grows with the
  number of submaps, so only equal counts compare.
- ``count_curve``: e of a baseline over a range of sizes, for the e-against-submaps figure.
- ``room_labels``: the ground-truth segmentation of a simulated robot (a submap per room
  visit, or per room with revisits merged): the e a perfect room segmentation gets.
"""

from __future__ import annotations

import itertools
import math
import statistics
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core import Reason
from lessmap.evaluation.baselines import fixed_features, fixed_frames
from lessmap.evaluation.data.segmentation import consecutive, run_lessmap, submap_features
from lessmap.evaluation.scores.infoloss import information_loss, landmark_submaps

if TYPE_CHECKING:
    from collections.abc import Collection, Sequence

    from numpy.typing import NDArray

    from lessmap.core import PartitionParams
    from lessmap.evaluation.data.segmentation import LessmapRun
    from lessmap.evaluation.scores.infoloss import LandmarkInformation
    from lessmap.files.frames import FrameRow
    from lessmap.sim.simulator import SimTruth


@dataclass(frozen=True, slots=True, kw_only=True)
class StreamStats:
    """Density of a feature stream (one robot)."""

    frames: int
    features_mean: float  # per frame
    features_median: float
    empty_share: float  # frames with no feature
    sightings_median: float  # frames per landmark
    run_mean: float  # consecutive frames a landmark stays in view (one sighting run)
    run_median: float


@dataclass(frozen=True, slots=True, kw_only=True)
class Loss:
    """e of one segmentation under both membership rules, and its submap count."""

    submaps: int
    e: float  # a landmark in every submap that saw it
    e_exclusive: float  # a landmark in the submap that saw it most


@dataclass(frozen=True, slots=True, kw_only=True)
class VariantRow:
    """One LESS-mapping variant next to the baselines cut to as many submaps."""

    name: str
    lessmap: Loss
    spectral: int
    disconnected: int
    size_median: float  # features per submap
    size_max: int
    small: int  # submaps with fewer than 5 features
    ncut_median: float | None  # at the spectral transitions
    overlap: float  # consecutive submaps: shared landmarks / all their landmarks (Jaccard)
    fixed_frames: Loss  # same number of submaps
    frames_length: int
    frames_overlap: float
    fixed_features: Loss  # nearest number of submaps
    features_limit: int


def stream_stats(frames: Sequence[Collection[int]]) -> StreamStats:
    """Return how dense a stream is: features per frame and how long features stay in view."""
    counts = np.asarray([len(set(f)) for f in frames], dtype=np.float64)
    sightings: dict[int, int] = {}
    runs: list[int] = []
    open_runs: dict[int, int] = {}
    for features in frames:
        current = set(features)
        for gone in set(open_runs) - current:
            runs.append(open_runs.pop(gone))
        for feature in current:
            open_runs[feature] = open_runs.get(feature, 0) + 1
            sightings[feature] = sightings.get(feature, 0) + 1
    runs += open_runs.values()
    return StreamStats(
        frames=len(frames),
        features_mean=float(counts.mean()) if counts.size else 0.0,
        features_median=float(np.median(counts)) if counts.size else 0.0,
        empty_share=float(np.mean(counts == 0)) if counts.size else 0.0,
        sightings_median=float(statistics.median(sightings.values())) if sightings else 0.0,
        run_mean=statistics.fmean(runs) if runs else 0.0,
        run_median=float(statistics.median(runs)) if runs else 0.0,
    )


def loss(
    info: LandmarkInformation,
    frames: Sequence[Collection[int]],
    labels: NDArray[np.int64],
) -> Loss:
    """Return e of a frame labelling under both membership rules."""
    return Loss(
        submaps=int(labels.max()) + 1 if labels.size else 0,
        e=information_loss(info, landmark_submaps(frames, labels)),
        e_exclusive=information_loss(info, landmark_submaps(frames, labels, exclusive=True)),
    )


def limit_for_count(frames: Sequence[Collection[int]], count: int) -> int:
    """Return the fixed-features limit whose submap count is nearest ``count`` (ties: larger).

    The count falls as the limit grows, so a bisection finds the crossing.
    """
    total = len({f for frame in frames for f in frame})

    def made(limit: int) -> int:
        return int(fixed_features(frames, limit).max()) + 1 if frames else 0

    low, high = 1, max(total, 1)
    while low < high:  # smallest limit with made(limit) <= count
        middle = (low + high) // 2
        if made(middle) <= count:
            high = middle
        else:
            low = middle + 1
    candidates = [limit for limit in (low - 1, low) if limit >= 1]
    return min(candidates, key=lambda limit: (abs(made(limit) - count), -limit))


def variant_row(
    name: str,
    frames: Sequence[FrameRow],
    info: LandmarkInformation,
    params: PartitionParams | None = None,
    run: LessmapRun | None = None,
) -> VariantRow:
    """Run one LESS-mapping variant (or take ``run``) and set it against equal-count baselines."""
    if run is None:
        if params is None:
            msg = "variant_row needs params or a run"
            raise ValueError(msg)
        run = run_lessmap(frames, params)
    features = [frame.features for frame in frames]
    mine = loss(info, features, run.labels)
    sizes = [len(s) for s in submap_features(features, run.labels)]
    length = max(1, math.ceil(len(frames) / max(mine.submaps, 1)))
    limit = limit_for_count(features, mine.submaps)
    frames_labels = fixed_frames(features, length)
    ncuts = [t.ncut for t in run.transitions if t.ncut is not None]
    reasons = [t.reason for t in run.transitions]
    return VariantRow(
        name=name,
        lessmap=mine,
        spectral=reasons.count(Reason.SPECTRAL),
        disconnected=reasons.count(Reason.DISCONNECTED),
        size_median=float(np.median(sizes)) if sizes else 0.0,
        size_max=max(sizes, default=0),
        small=sum(size < 5 for size in sizes),
        ncut_median=float(np.median(ncuts)) if ncuts else None,
        overlap=boundary_overlap(features, run.labels),
        fixed_frames=loss(info, features, frames_labels),
        frames_length=length,
        frames_overlap=boundary_overlap(features, frames_labels),
        fixed_features=loss(info, features, fixed_features(features, limit)),
        features_limit=limit,
    )


def boundary_overlap(frames: Sequence[Collection[int]], labels: NDArray[np.int64]) -> float:
    """Return the mean Jaccard index of the landmark sets of consecutive submaps (0 if < 2).

    Low: the segmentation cuts where few landmarks are seen on both sides.
    """
    sets = submap_features(frames, labels)
    pairs = [len(a & b) / len(a | b) for a, b in itertools.pairwise(sets) if a | b]
    return statistics.fmean(pairs) if pairs else 0.0


def count_curve(
    frames: Sequence[Collection[int]],
    info: LandmarkInformation,
    kind: str,
    sizes: Sequence[int],
) -> list[Loss]:
    """Return e of the ``fixed_features`` or ``fixed_frames`` baseline for each size."""
    cut = {"features": fixed_features, "frames": fixed_frames}[kind]
    return [loss(info, frames, cut(frames, size)) for size in sizes]


def off_diagonal_share(info: LandmarkInformation) -> float:
    """Return e of the finest partition (every landmark alone): the ceiling of e."""
    total = float(info.block_mass.sum())
    return 0.0 if total == 0.0 else 1.0 - float(np.trace(info.block_mass)) / total


def room_labels(frames: Sequence[FrameRow], truth: SimTruth, *, merged: bool) -> NDArray[np.int64]:
    """Label one robot's frames by its true room: a submap per visit, or per room if merged.

    Raises:
        KeyError: a frame has no truth row.
    """
    room_of = {(row.robot, row.seq): row.room for row in truth.rows}
    rooms = np.asarray([room_of[(f.robot, f.seq)] for f in frames], dtype=np.int64)
    if merged:
        return consecutive(rooms)
    changes = np.concatenate([[0], np.cumsum(rooms[1:] != rooms[:-1])]) if rooms.size else rooms
    return changes.astype(np.int64)

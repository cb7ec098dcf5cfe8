"""Threshold sweep: e and submap sizes over a grid of (Ncut_min, λ2_min) (paper §4.1, Fig. 6)."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from lessmap.core import Reason
from lessmap.evaluation.data.segmentation import run_lessmap, submap_stats
from lessmap.evaluation.scores.infoloss import information_loss, landmark_submaps
from lessmap.progress import NO_PROGRESS, tracked

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from lessmap.core import PartitionParams
    from lessmap.evaluation.data.segmentation import LessmapRun, SubmapStats
    from lessmap.evaluation.scores.infoloss import LandmarkInformation
    from lessmap.files.frames import FrameRow
    from lessmap.progress import Progress

#: The default grid: both thresholds from 0.1 to 0.5 in steps of 0.1 (25 runs).
DEFAULT_GRID: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5)

RunKey = tuple[float, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class SweepRow:
    """The outcome of one threshold pair."""

    ncut_min: float
    lambda2_min: float
    e: float  # a landmark in every submap that observed it
    e_exclusive: float  # a landmark in the one submap that observed it most
    stats: SubmapStats
    spectral: int  # transitions by Eq. 4
    disconnected: int  # transitions by a disconnected CovGraph

    def as_dict(self) -> dict[str, float | int]:
        """Return the row as JSON-ready values."""
        return {
            "ncut_min": self.ncut_min,
            "lambda2_min": self.lambda2_min,
            "e": self.e,
            "e_exclusive": self.e_exclusive,
            "spectral": self.spectral,
            "disconnected": self.disconnected,
            **self.stats.as_dict(),
        }


def run_grid(
    frames: Sequence[FrameRow],
    base: PartitionParams,
    pairs: Iterable[RunKey],
    *,
    jobs: int = 1,
    known: dict[RunKey, LessmapRun] | None = None,
    progress: Progress = NO_PROGRESS,
) -> dict[RunKey, LessmapRun]:
    """Run the partitioner once per (Ncut_min, λ2_min) pair not already in ``known``.

    Args:
        frames: one robot's frames.
        base: parameters of every run except the two thresholds.
        pairs: the threshold pairs.
        jobs: worker processes (1: run here, in order). Workers are spawned, so a script
            that calls this with jobs > 1 needs an ``if __name__ == "__main__":`` guard
            (the ``lessmap`` command and ``python -m lessmap`` are safe).
        known: runs already made; they are reused and the new ones are added to it.
        progress: advanced by one per run made.
    """
    runs = known if known is not None else {}
    todo = [pair for pair in dict.fromkeys(pairs) if pair not in runs]
    params = [replace(base, ncut_min=ncut, lambda2_min=lam) for ncut, lam in todo]
    if jobs > 1 and len(todo) > 1:
        context = multiprocessing.get_context("spawn")  # no fork of a threaded parent
        with ProcessPoolExecutor(min(jobs, len(todo)), mp_context=context) as pool:
            results = list(tracked(pool.map(run_lessmap, [frames] * len(todo), params), progress))
    else:
        results = list(tracked((run_lessmap(frames, p) for p in params), progress))
    runs.update(zip(todo, results, strict=True))
    return runs


def sweep_row(frames: Sequence[FrameRow], info: LandmarkInformation, run: LessmapRun) -> SweepRow:
    """Return the figures of one run."""
    features = [frame.features for frame in frames]
    reasons = [t.reason for t in run.transitions]
    return SweepRow(
        ncut_min=run.params.ncut_min,
        lambda2_min=run.params.lambda2_min,
        e=information_loss(info, landmark_submaps(features, run.labels)),
        e_exclusive=information_loss(info, landmark_submaps(features, run.labels, exclusive=True)),
        stats=submap_stats(features, run.labels),
        spectral=reasons.count(Reason.SPECTRAL),
        disconnected=reasons.count(Reason.DISCONNECTED),
    )


def sweep(
    frames: Sequence[FrameRow],
    info: LandmarkInformation,
    base: PartitionParams,
    ncut_values: Sequence[float] = DEFAULT_GRID,
    lambda2_values: Sequence[float] = DEFAULT_GRID,
    *,
    jobs: int = 1,
    known: dict[RunKey, LessmapRun] | None = None,
    progress: Progress = NO_PROGRESS,
) -> list[SweepRow]:
    """Run the partitioner over the grid Ncut_min × λ2_min; return one row per pair.

    Rows come in grid order: Ncut_min outer, λ2_min inner. ``progress`` gets one stage, a
    step per run.
    """
    pairs = [(float(n), float(lam)) for n in ncut_values for lam in lambda2_values]
    todo = {pair for pair in pairs if known is None or pair not in known}
    if pairs:
        progress.stage(f"threshold sweep, {len(pairs)} pairs", len(todo))
    runs = run_grid(frames, base, pairs, jobs=jobs, known=known, progress=progress)
    return [sweep_row(frames, info, runs[pair]) for pair in pairs]


def format_table(rows: Sequence[SweepRow]) -> str:
    """Return the sweep as an aligned text table (e in percent)."""
    header = (
        f"{'Ncut_min':>8} {'λ2_min':>7} {'e %':>8} {'e excl %':>8} {'submaps':>7} {'spectral':>8} "
        f"{'disconn.':>8} {'feat mean':>9} {'min':>4} {'max':>4}"
    )
    lines = [header, "-" * len(header)]
    for row in rows:
        s = row.stats
        lines.append(
            f"{row.ncut_min:8.3g} {row.lambda2_min:7.3g} {100 * row.e:8.3f} "
            f"{100 * row.e_exclusive:8.3f} {s.submaps:7d} "
            f"{row.spectral:8d} {row.disconnected:8d} {s.features_mean:9.1f} "
            f"{s.features_min:4d} {s.features_max:4d}"
        )
    return "\n".join(lines) + "\n"

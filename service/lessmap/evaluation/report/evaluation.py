"""The evaluation of one data set: e (Eq. 5) of LESS-mapping next to the baselines, a sweep."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.evaluation.baselines import fixed_features, fixed_frames, single_submap
from lessmap.evaluation.data.segmentation import consecutive, submap_stats
from lessmap.evaluation.scores.infoloss import (
    DEFAULT_ANCHOR_INFORMATION,
    information_loss,
    landmark_information,
    landmark_submaps,
)
from lessmap.evaluation.studies.sweep import DEFAULT_GRID, format_table, run_grid, sweep
from lessmap.progress import NO_PROGRESS

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from lessmap.core import PartitionParams
    from lessmap.core.areas.tracker import AreaParams
    from lessmap.evaluation.data.dataset import Dataset
    from lessmap.evaluation.data.segmentation import LessmapRun, SubmapStats
    from lessmap.evaluation.scores.infoloss import LandmarkInformation
    from lessmap.evaluation.studies.sweep import RunKey, SweepRow
    from lessmap.progress import Progress


@dataclass(frozen=True, slots=True, kw_only=True)
class MethodResult:
    """e and submap sizes of one segmentation method."""

    name: str
    e: float  # a landmark in every submap that observed it
    e_exclusive: float  # a landmark in the one submap that observed it most
    stats: SubmapStats
    labels: NDArray[np.int64]  # frame → submap

    def as_dict(self) -> dict[str, Any]:
        """Return the result as JSON-ready values (labels left out)."""
        return {
            "method": self.name,
            "e": self.e,
            "e_exclusive": self.e_exclusive,
            **self.stats.as_dict(),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class EvalReport:
    """Everything ``lessmap eval`` reports about one data set."""

    dataset: str
    robot: str
    frames: int
    landmarks: int
    params: PartitionParams
    info: LandmarkInformation
    methods: tuple[MethodResult, ...]  # LESS-mapping first
    lessmap: LessmapRun
    sweep: tuple[SweepRow, ...]
    elapsed_s: float
    source_note: str = ""  # where H comes from when not from the data set's files

    def as_dict(self) -> dict[str, Any]:
        """Return the report as JSON-ready values."""
        return {
            "dataset": self.dataset,
            "robot": self.robot,
            "frames": self.frames,
            "landmarks": self.landmarks,
            "params": {
                "ncut_min": self.params.ncut_min,
                "lambda2_min": self.params.lambda2_min,
                "seed_mode": str(self.params.seed_mode),
            },
            "information": {
                "anchor_information": self.info.anchor_information,
                "unit_information_edges": self.info.unit_information_edges,
                "diagonal_blocks_in_denominator": True,
                "source": self.source_note or "edges and odometry files of the data set",
                "membership": "e: a landmark belongs to every submap that observed it; a pair "
                "is lost when the two share no submap. e_exclusive: a landmark belongs to the "
                "one submap that observed it most often",
            },
            "methods": [m.as_dict() for m in self.methods],
            "sweep": [row.as_dict() for row in self.sweep],
            "elapsed_s": round(self.elapsed_s, 2),
        }

    def notes(self) -> list[str]:
        """Return the lines that say what was measured and how H was built."""
        unit = self.info.unit_information_edges
        return [
            f"data set {self.dataset} (robot {self.robot}): {self.frames} frames, "
            f"{self.landmarks} landmarks",
            *([self.source_note] if self.source_note else []),
            "H: poses marginalized (Schur complement), first pose anchored with prior "
            f"{self.info.anchor_information:g}·I; diagonal blocks count in the denominator",
            f"unit information used for {unit} edges without noise"
            if unit
            else "information as given by the data set (no unit substitutes)",
        ]

    def to_text(self) -> str:
        """Return the report as plain text (what ``lessmap eval`` prints)."""
        width = max(len(m.name) for m in self.methods)
        header = f"{'method':<{width}} {'e %':>8} {'e excl %':>8} {'submaps':>7} "
        header += f"{'feat mean':>9} {'min':>4} {'max':>4} {'frames mean':>11}"
        lines = [*self.notes(), "", header, "-" * len(header)]
        for m in self.methods:
            s = m.stats
            lines.append(
                f"{m.name:<{width}} {100 * m.e:8.3f} {100 * m.e_exclusive:8.3f} {s.submaps:7d} "
                f"{s.features_mean:9.1f} {s.features_min:4d} {s.features_max:4d} "
                f"{s.frames_mean:11.1f}"
            )
        if self.sweep:
            lines += ["", "threshold sweep (LESS-mapping):", format_table(self.sweep).rstrip()]
        return "\n".join(lines) + "\n"

    def to_markdown(self) -> str:
        """Return the report as Markdown tables."""
        lines = [f"# Information loss on {self.dataset}", ""]
        lines += [f"- {note}" for note in self.notes()]
        lines += [
            "",
            "| method | e (%) | e exclusive (%) | submaps | features mean | min | max | "
            "frames mean |",
            "|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for m in self.methods:
            s = m.stats
            lines.append(
                f"| {m.name} | {100 * m.e:.3f} | {100 * m.e_exclusive:.3f} | {s.submaps} | "
                f"{s.features_mean:.1f} | {s.features_min} | {s.features_max} | "
                f"{s.frames_mean:.1f} |"
            )
        if self.sweep:
            lines += [
                "",
                "## Threshold sweep",
                "",
                "| Ncut_min | λ2_min | e (%) | e exclusive (%) | submaps | spectral | "
                "disconnected | features mean | max |",
                "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
            ]
            for row in self.sweep:
                lines.append(
                    f"| {row.ncut_min:g} | {row.lambda2_min:g} | {100 * row.e:.3f} | "
                    f"{100 * row.e_exclusive:.3f} | "
                    f"{row.stats.submaps} | {row.spectral} | {row.disconnected} | "
                    f"{row.stats.features_mean:.1f} | {row.stats.features_max} |"
                )
        return "\n".join(lines) + "\n"


def fixed_frames_row(report: EvalReport) -> MethodResult:
    """Return the fixed-frames baseline cut to the paper run's submap count."""
    return next(
        m for m in report.methods if m.name.startswith("fixed-") and m.name.endswith(" frames")
    )


def evaluate(
    dataset: Dataset,
    params: PartitionParams,
    *,
    feature_limits: Sequence[int] = (50, 60),
    frames_per_submap: int | None = None,
    ncut_values: Sequence[float] = DEFAULT_GRID,
    lambda2_values: Sequence[float] = DEFAULT_GRID,
    jobs: int = 1,
    anchor_information: float = DEFAULT_ANCHOR_INFORMATION,
    areas: AreaParams | None = None,
    progress: Progress = NO_PROGRESS,
) -> EvalReport:
    """Compute e for LESS-mapping, the baselines and a threshold sweep on one data set.

    Args:
        dataset: frames and SLAM problem of one robot.
        params: the LESS-mapping parameters of the main run (the sweep varies the thresholds).
        feature_limits: one fixed-features baseline per limit (Estrada et al.: 50, 60).
        frames_per_submap: length of the fixed-frames baseline; None: as many submaps as
            LESS-mapping made.
        ncut_values: sweep grid (empty: no sweep).
        lambda2_values: sweep grid (empty: no sweep).
        jobs: worker processes for the sweep.
        anchor_information: the first-pose prior (see ``lessmap.evaluation.scores.infoloss``).
        areas: also segment with ``lessmap.core.areas.tracker``: its segments, its areas (revisits
            merged) and fixed frames cut to as many submaps as it has segments, appended
            after the paper's rows.
        progress: where the runs are counted, a stage per method and one for the sweep.
    """
    started = time.perf_counter()
    frames = dataset.frames
    features = [frame.features for frame in frames]
    info = landmark_information(dataset.problem, anchor_information)
    main_key: RunKey = (params.ncut_min, params.lambda2_min)
    progress.stage("LESS-mapping", 1)
    runs: dict[RunKey, LessmapRun] = run_grid(frames, params, [main_key], progress=progress)
    main = runs[main_key]

    def result(name: str, labels: NDArray[np.int64]) -> MethodResult:
        return MethodResult(
            name=name,
            e=information_loss(info, landmark_submaps(features, labels)),
            e_exclusive=information_loss(info, landmark_submaps(features, labels, exclusive=True)),
            stats=submap_stats(features, labels),
            labels=labels,
        )

    methods = [
        result(f"lessmap (Ncut≤{params.ncut_min:g}, λ2≤{params.lambda2_min:g})", main.labels)
    ]
    methods += [result(f"fixed-{n} features", fixed_features(features, n)) for n in feature_limits]
    count = int(main.labels.max()) + 1 if main.labels.size else 1
    length = frames_per_submap or max(1, math.ceil(len(frames) / count))
    methods.append(result(f"fixed-{length} frames", fixed_frames(features, length)))
    methods.append(result("no partition", single_submap(features)))
    if areas is not None:
        from lessmap.evaluation.methods import area_of_frames, run_method

        progress.stage("areas", 1)
        events = run_method(frames, "areas", areas=areas).get(dataset.robot, [])
        seqs = [frame.seq for frame in frames]
        starts = [event.boundary_seq for event in events]
        segments = np.searchsorted(np.sort(starts), seqs, side="right").astype(np.int64)
        merged = np.asarray(area_of_frames(seqs, events), dtype=np.int64)
        methods.append(result("areas (segments)", consecutive(segments)))
        methods.append(result("areas (revisits merged)", consecutive(merged)))
        length = max(1, math.ceil(len(frames) / (len(events) + 1)))
        methods.append(
            result(f"fixed-{length} frames (areas' count)", fixed_frames(features, length))
        )
        progress.advance()
    rows = sweep(
        frames, info, params, ncut_values, lambda2_values, jobs=jobs, known=runs, progress=progress
    )
    return EvalReport(
        dataset=dataset.name,
        robot=dataset.robot,
        frames=len(frames),
        landmarks=int(info.landmark_ids.size),
        params=params,
        info=info,
        methods=tuple(methods),
        lessmap=main,
        sweep=tuple(rows),
        elapsed_s=time.perf_counter() - started,
        source_note=dataset.note,
    )

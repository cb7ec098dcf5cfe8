"""The figures of the results page, measured: a recorded data set and a simulated run.

``recorded`` evaluates a recorded data set (frames, edges, odometry), ``simulated`` a run of
the seeded simulator (its files, read with ``lessmap.sim``), each into a plain results
object. Every number on ``docs/RESULTS.md`` is measured here; the page itself is rendered
outside the package, by ``docs/results/generate.py``, which imports this module (never the
other way round).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core import PartitionParams, SeedMode
from lessmap.evaluation.data.dataset import load_dataset
from lessmap.evaluation.data.simrun import load_for_eval, load_truth
from lessmap.evaluation.report.evaluation import evaluate, fixed_frames_row
from lessmap.evaluation.scores.consistency import (
    fixed_feature_detections,
    lessmap_detections,
    score,
)
from lessmap.evaluation.scores.infoloss import landmark_information
from lessmap.evaluation.studies.diagnosis import (
    count_curve,
    loss,
    off_diagonal_share,
    room_labels,
    stream_stats,
    variant_row,
)
from lessmap.files.frames import read_frames

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.evaluation.report.evaluation import EvalReport
    from lessmap.evaluation.scores.consistency import Consistency, Detection
    from lessmap.evaluation.studies.diagnosis import Loss, StreamStats, VariantRow
    from lessmap.files.frames import FrameRow
    from lessmap.sim.simulator import SimTruth

FEATURE_SIZES = (10, 15, 20, 30, 50, 60, 100, 150)  # the fixed-features curve
FRAME_SIZES = (10, 20, 30, 50, 100, 165, 300)  # the fixed-frames curve
ODOMETRY_SCALES = (1.0, 0.1, 0.01)


def variants(base: PartitionParams) -> list[tuple[str, str, PartitionParams]]:
    """Return the LESS-mapping variants of the "why" table: (name, eval options, params)."""
    return [
        ("seed_mode=fresh", "--seed-mode fresh", replace(base, seed_mode=SeedMode.FRESH)),
        ("min_frames_between=20", "--min-frames-between 20", replace(base, min_frames_between=20)),
        ("min_frames_between=40", "--min-frames-between 40", replace(base, min_frames_between=40)),
        ("min_cluster_size=3", "--min-cluster-size 3", replace(base, min_cluster_size=3)),
        ("min_cluster_size=5", "--min-cluster-size 5", replace(base, min_cluster_size=5)),
        ("min_cluster_size=10", "--min-cluster-size 10", replace(base, min_cluster_size=10)),
        (
            "Ncut≤0.1, λ2≤0.1",
            "--ncut-min 0.1 --lambda2-min 0.1",
            replace(base, ncut_min=0.1, lambda2_min=0.1),
        ),
    ]


@dataclass(frozen=True, slots=True, kw_only=True)
class RecordedResults:
    """The recorded data set: evaluation, stream, variants, information scale, curves."""

    path: str  # as given on the command line
    report: EvalReport
    frames: tuple[FrameRow, ...]
    stream: StreamStats
    rows: tuple[tuple[str, VariantRow], ...]  # (lessmap eval options, row), paper first
    scales: tuple[tuple[float, Loss, Loss, Loss], ...]  # scale, lessmap, fixed-50, fixed frames
    ceiling: float  # e of the finest partition
    odometry_ratio: float  # median odometry xx information / median landmark xx information
    path_m: float  # length of the pose chain (the data set's poses)
    curves: dict[str, list[tuple[int, float, float]]]


@dataclass(frozen=True, slots=True, kw_only=True)
class SimResults:
    """The simulated run: e per robot, consistency of all robots."""

    path: str
    reports: tuple[EvalReport, ...]  # one per robot
    frames: tuple[FrameRow, ...]  # the first robot's
    rows: tuple[VariantRow, ...]  # paper thresholds per robot, with equal-count baselines
    rooms: tuple[tuple[Loss, Loss], ...]  # per robot: true rooms per visit, merged
    stream: StreamStats  # first robot
    truth: SimTruth
    consistency: tuple[Consistency, ...]  # LESS-mapping, fixed-50
    detections: dict[str, list[Detection]]


def recorded(
    path: Path, params: PartitionParams, grid: Sequence[float], jobs: int
) -> RecordedResults:
    """Evaluate the recorded data set and collect the figures of the "why" section."""
    dataset = load_dataset(path)
    report = evaluate(dataset, params, ncut_values=grid, lambda2_values=grid, jobs=jobs)
    frames = dataset.frames
    features = [frame.features for frame in frames]
    info = report.info
    rows = [("", variant_row("paper thresholds", frames, info, run=report.lessmap))]
    rows += [(opts, variant_row(name, frames, info, p)) for name, opts, p in variants(params)]
    scales = []
    for scale in ODOMETRY_SCALES:
        problem = dataset.problem
        scaled = landmark_information(
            replace(problem, odo_information=problem.odo_information * scale)
        )
        main = report.methods[0].labels
        scales.append(
            (
                scale,
                loss(scaled, features, main),
                loss(scaled, features, report.methods[1].labels),
                loss(scaled, features, fixed_frames_row(report).labels),
            )
        )
    curves = {
        "lessmap (sweep)": [(r.stats.submaps, r.e, r.e_exclusive) for r in report.sweep],
        "lessmap (guards, seed mode)": [
            (row.lessmap.submaps, row.lessmap.e, row.lessmap.e_exclusive) for _, row in rows
        ],
        "fixed features": [
            (x.submaps, x.e, x.e_exclusive)
            for x in count_curve(features, info, "features", FEATURE_SIZES)
        ],
        "fixed frames": [
            (x.submaps, x.e, x.e_exclusive)
            for x in count_curve(features, info, "frames", FRAME_SIZES)
        ],
    }
    return RecordedResults(
        path=str(path),
        report=report,
        frames=frames,
        stream=stream_stats(features),
        rows=tuple(rows),
        scales=tuple(scales),
        ceiling=off_diagonal_share(info),
        path_m=float(np.hypot(*np.diff(dataset.problem.poses[:, :2], axis=0).T).sum()),
        odometry_ratio=float(
            np.median(dataset.problem.odo_information[:, 0])
            / np.median(dataset.problem.obs_information[:, 0])
        ),
        curves=curves,
    )


def simulated(path: Path, params: PartitionParams) -> SimResults:
    """Evaluate every robot of a simulated run and score all robots against the truth."""
    frames = list(read_frames(path))
    robots = sorted({frame.robot for frame in frames})
    truth = load_truth(path)
    reports, rows, first = [], [], None
    rooms: list[tuple[Loss, Loss]] = []
    for robot in robots:
        dataset = load_for_eval(path, robot)
        first = first or dataset.frames
        report = evaluate(dataset, params, ncut_values=(), lambda2_values=())
        reports.append(report)
        rows.append(variant_row(robot, dataset.frames, report.info, run=report.lessmap))
        features = [frame.features for frame in dataset.frames]
        visits, merged = (
            loss(report.info, features, room_labels(dataset.frames, truth, merged=flag))
            for flag in (False, True)
        )
        rooms.append((visits, merged))
    name = f"lessmap (Ncut≤{params.ncut_min:g}, λ2≤{params.lambda2_min:g})"
    detections = {
        name: lessmap_detections(frames, params),
        "fixed-50 features": fixed_feature_detections(frames, 50),
    }
    consistency = tuple(score(truth, found, method=m) for m, found in detections.items())
    return SimResults(
        path=str(path),
        reports=tuple(reports),
        frames=first or (),
        rows=tuple(rows),
        rooms=tuple(rooms),
        stream=stream_stats([f.features for f in frames if f.robot == robots[0]]),
        truth=truth,
        consistency=consistency,
        detections=detections,
    )

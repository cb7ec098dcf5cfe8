"""Write ``docs/RESULTS.md`` and ``docs/figures/*.png``: the one command behind the results page.

    python -m lessmap.evaluation.results --sim /tmp/sim/sim.frames.jsonl --out docs --jobs 2

It evaluates a recorded data set (default: DLR from ``../shared/datasets``) and a simulated
run (frames, truth and building files of ``lessmap.sim.simulator.write_run``; this
package may not import the simulator, so its files are the input), then renders the page
with ``lessmap.evaluation.resultsdoc``. Every figure on the page is measured here; the page
names, for each table, the ``lessmap eval`` command that gives the same numbers.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core import PartitionParams, SeedMode
from lessmap.evaluation.consistency import (
    fixed_feature_detections,
    lessmap_detections,
    score,
)
from lessmap.evaluation.dataset import load_dataset
from lessmap.evaluation.diagnosis import (
    count_curve,
    loss,
    off_diagonal_share,
    room_labels,
    stream_stats,
    variant_row,
)
from lessmap.evaluation.infoloss import landmark_information
from lessmap.evaluation.report import evaluate
from lessmap.evaluation.simrun import load_for_eval, load_truth
from lessmap.evaluation.sweep import DEFAULT_GRID
from lessmap.frames_file import read_frames

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.evaluation.consistency import Consistency, Detection
    from lessmap.evaluation.diagnosis import Loss, StreamStats, VariantRow
    from lessmap.evaluation.report import EvalReport
    from lessmap.frames_file import FrameRow
    from lessmap.sim.simulator import SimTruth

DEFAULT_DATASET = Path("../shared/datasets/dlr.frames.jsonl")
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
                loss(scaled, features, report.methods[-2].labels),
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


def write_figures(folder: Path, rec: RecordedResults, sim: SimResults | None) -> list[Path]:
    """Write the PNGs of the page into ``folder``; return their paths."""
    from lessmap.evaluation import charts, plots

    folder.mkdir(parents=True, exist_ok=True)
    report, name = rec.report, rec.report.dataset
    figures = {
        f"{name}_trajectory.png": plots.trajectory_figure(rec.frames, report.lessmap),
        f"{name}_ncut_lambda2.png": plots.thresholds_figure(report.lessmap),
        f"{name}_sweep.png": plots.sweep_figure(report.sweep) if report.sweep else None,
        f"{name}_e_vs_submaps.png": charts.loss_count_figure(
            rec.curves, f"{name}: e against the number of submaps"
        ),
    }
    if sim is not None:
        first = sim.reports[0]
        figures["sim_trajectory.png"] = plots.trajectory_figure(sim.frames, first.lessmap)
        figures["sim_consistency.png"] = charts.consistency_figure(sim.truth, sim.detections)
    written = []
    for file_name, fig in figures.items():
        if fig is None:
            continue
        path = folder / file_name
        fig.savefig(path, format="png", bbox_inches="tight", dpi=charts.DPI)
        written.append(path)
    return written


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of ``python -m lessmap.evaluation.results``."""
    parser = argparse.ArgumentParser(
        prog="python -m lessmap.evaluation.results",
        description="Evaluate a recorded data set and a simulated run; write RESULTS.md and "
        "figures/*.png into --out.",
    )
    parser.add_argument(
        "--dataset",
        type=Path,
        default=DEFAULT_DATASET,
        metavar="FILE",
        help=f"recorded frames file with edges and odometry (default {DEFAULT_DATASET})",
    )
    parser.add_argument(
        "--sim",
        type=Path,
        metavar="FILE",
        help="frames file of a simulated run (truth and building files next to it)",
    )
    parser.add_argument("--out", type=Path, default=Path("docs"), metavar="DIR")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes for the sweep")
    parser.add_argument(
        "--sweep",
        type=float,
        nargs="+",
        default=list(DEFAULT_GRID),
        metavar="V",
        help="values of both thresholds in the sweep (default 0.1..0.5)",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the evaluations and write the page; return the exit code."""
    from lessmap.errors import DatasetError
    from lessmap.evaluation.resultsdoc import render

    args = build_parser().parse_args(argv)
    started = time.perf_counter()
    params = PartitionParams.from_profile("laser")
    try:
        rec = recorded(args.dataset, params, args.sweep, max(args.jobs, 1))
        sim = simulated(args.sim, params) if args.sim is not None else None
    except (DatasetError, FileNotFoundError) as exc:
        sys.stderr.write(f"results: {exc}\n")
        return 1
    out: Path = args.out
    written = write_figures(out / "figures", rec, sim)
    page = render(rec, sim, [path.name for path in written], list(argv or sys.argv[1:]))
    (out / "RESULTS.md").write_text(page, encoding="utf-8")
    elapsed = time.perf_counter() - started
    lines = [f"wrote {path}" for path in [out / "RESULTS.md", *written]]
    sys.stdout.write("\n".join([*lines, f"({elapsed:.0f} s)"]) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

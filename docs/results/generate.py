"""Write ``docs/RESULTS.md`` and ``docs/figures/*.png``: the one command behind the results page.

    python docs/results/generate.py --sim /tmp/sim/sim.frames.jsonl --out docs --jobs 2

Run from the repository root. It evaluates a recorded data set (default: DLR from
``../shared/datasets``) and a simulated run (the files of ``lessmap sim --out``) with
``lessmap.evaluation.report.results_page``, draws the figures and renders the page with
``render.py`` beside this file. The imports go one way: this folder imports the ``lessmap``
package, the package never imports this folder.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from render import COMMAND, render

from lessmap.core import PartitionParams
from lessmap.errors import DatasetError
from lessmap.evaluation.report.results_page import RecordedResults, SimResults, recorded, simulated
from lessmap.evaluation.studies.sweep import DEFAULT_GRID

if TYPE_CHECKING:
    from collections.abc import Sequence

DEFAULT_DATASET = Path("../shared/datasets/dlr.frames.jsonl")


def write_figures(folder: Path, rec: RecordedResults, sim: SimResults | None) -> list[Path]:
    """Write the PNGs of the page into ``folder``; return their paths."""
    from lessmap.evaluation.figures import building as charts, segmentation as plots

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
    """Return the parser of this script."""
    parser = argparse.ArgumentParser(
        prog=shlex.join(COMMAND),
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
        "--areas-seeds",
        type=int,
        default=5,
        metavar="N",
        help="simulated runs per case of the areas comparison (0: leave it out; default 5)",
    )
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
    args = build_parser().parse_args(argv)
    started = time.perf_counter()
    params = PartitionParams.from_profile("laser")
    try:
        rec = recorded(args.dataset, params, args.sweep, max(args.jobs, 1))
        sim = simulated(args.sim, params) if args.sim is not None else None
        areas = area_graph = None
        if args.areas_seeds > 0:
            from lessmap.evaluation.studies.areabench import report

            areas = report(args.areas_seeds, args.dataset.parent)
            from lessmap.evaluation.scores.area_graphs import CONTAINMENTS, report as graph_report

            area_graph = graph_report(args.areas_seeds, args.dataset.parent, CONTAINMENTS)
    except (DatasetError, FileNotFoundError) as exc:
        sys.stderr.write(f"results: {exc}\n")
        return 1
    out: Path = args.out
    written = write_figures(out / "figures", rec, sim)
    page = render(
        rec,
        sim,
        [path.name for path in written],
        list(argv or sys.argv[1:]),
        areas=areas,
        area_graph=area_graph,
    )
    (out / "RESULTS.md").write_text(page, encoding="utf-8")
    elapsed = time.perf_counter() - started
    lines = [f"wrote {path}" for path in [out / "RESULTS.md", *written]]
    sys.stdout.write("\n".join([*lines, f"({elapsed:.0f} s)"]) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The ``lessmap eval`` and ``lessmap plot`` subcommands (wired into ``lessmap.cli.app``)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap.config.partitioning import (
    add_partition_options,
    area_params,
    partition_params,
    partition_settings,
)
from lessmap.core import PartitionParams
from lessmap.errors import ConfigError
from lessmap.evaluation.scores.consistency import DEFAULT_DOOR_DISTANCE_M, DEFAULT_TOLERANCE_FRAMES
from lessmap.evaluation.scores.infoloss import DEFAULT_ANCHOR_INFORMATION
from lessmap_client.cli_options import positive_int

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.core.areas.graph import AreaGraph
    from lessmap.evaluation.data.dataset import Dataset
    from lessmap.evaluation.scores.consistency import Consistency, Detection
    from lessmap.files.frames import FrameRow
    from lessmap.sim.simulator import SimTruth
    from lessmap_client.fleet_areas import FleetGraph


def _add_common(parser: argparse.ArgumentParser, *, file_optional: bool = False) -> None:
    parser.add_argument(
        "file",
        metavar="FILE",
        type=Path,
        nargs="?" if file_optional else None,
        help="frames file (.frames.jsonl)",
    )
    parser.add_argument(
        "--robot",
        help="robot to evaluate (needed when a recorded file has several; a simulated run "
        "defaults to its first robot)",
    )
    add_partition_options(parser)
    sweep = parser.add_argument_group("threshold sweep")
    sweep.add_argument(
        "--sweep-ncut",
        type=float,
        nargs="+",
        metavar="V",
        default=[0.1, 0.2, 0.3, 0.4, 0.5],
        help="Ncut_min values (default 0.1..0.5)",
    )
    sweep.add_argument(
        "--sweep-lambda2",
        type=float,
        nargs="+",
        metavar="V",
        default=[0.1, 0.2, 0.3, 0.4, 0.5],
        help="λ2_min values (default 0.1..0.5)",
    )
    sweep.add_argument("--no-sweep", action="store_true", help="skip the sweep")
    sweep.add_argument(
        "--jobs", type=positive_int, default=1, help="worker processes for the sweep"
    )


def _params(args: argparse.Namespace) -> PartitionParams:
    return partition_params(args)


def _warn_if_sparse(command: str, path: Path, frames: Sequence[FrameRow]) -> None:
    """One line on stderr when the frames hold too few features to be covisible."""
    from lessmap.files.frames import sparse_frames_warning

    features = sum(len(frame.features) for frame in frames)
    warning = sparse_frames_warning(str(path), len(frames), features)
    if warning is not None:
        sys.stderr.write(f"lessmap {command}: {warning}\n")


def _grid(args: argparse.Namespace) -> tuple[list[float], list[float]]:
    if args.no_sweep:
        return [], []
    return list(args.sweep_ncut), list(args.sweep_lambda2)


def run_eval(args: argparse.Namespace) -> int:
    """Print e of LESS-mapping and the baselines, and the sweep; write files with --out.

    On a simulated run (``<name>.truth.jsonl`` next to FILE) it also scores the transitions
    of every robot against the true room changes (``lessmap.evaluation.scores.consistency``).
    """
    from lessmap.cli.progress import progress
    from lessmap.evaluation.data.simrun import is_sim_run, load_for_eval
    from lessmap.evaluation.report.evaluation import evaluate
    from lessmap.evaluation.report.markdown import describe, eval_markdown

    params = _params(args)
    if args.plots and args.out is None:
        msg = "--plots needs --out DIR"
        raise ConfigError(msg)
    sizes = [*args.fixed_features, *([args.fixed_frames] if args.fixed_frames else [])]
    if any(size < 1 for size in sizes) or args.fixed_frames == 0:
        msg = "--fixed-features and --fixed-frames need sizes of at least 1"
        raise ConfigError(msg)
    if not args.anchor_information > 0:
        msg = f"--anchor-information must be positive, got {args.anchor_information}"
        raise ConfigError(msg)
    if not args.odometry_scale > 0:
        msg = f"--odometry-scale must be positive, got {args.odometry_scale}"
        raise ConfigError(msg)
    ncuts, lams = _grid(args)
    with progress(args) as shown:
        shown.stage(f"reading {Path(args.file).name}")
        dataset = scale_odometry(load_for_eval(args.file, args.robot), args.odometry_scale)
        _warn_if_sparse("eval", args.file, dataset.frames)
        report = evaluate(
            dataset,
            params,
            feature_limits=args.fixed_features,
            frames_per_submap=args.fixed_frames,
            ncut_values=ncuts,
            lambda2_values=lams,
            jobs=args.jobs,
            anchor_information=args.anchor_information,
            areas=area_params(partition_settings(args)),
            progress=shown,
        )
        sys.stdout.write(report.to_text())
        truth: SimTruth | None = None
        consistency: list[Consistency] = []
        detections: dict[str, list[Detection]] = {}
        if is_sim_run(args.file):
            shown.stage("consistency with the ground truth")
            truth, consistency, detections = _consistency(args, params)
        sys.stdout.write("\nconsistency with the ground truth (all robots):\n")
        sys.stdout.write("".join(describe(result) + "\n" for result in consistency))
    if args.out is not None:
        out: Path = args.out
        out.mkdir(parents=True, exist_ok=True)
        document = report.as_dict() | {"consistency": [c.as_dict() for c in consistency]}
        (out / "eval.json").write_text(json.dumps(document, indent=1) + "\n", "utf-8")
        figures: list[Path] = []
        if args.plots:
            from lessmap.evaluation.figures.segmentation import write_plots

            figures += write_plots(out, dataset.frames, report.lessmap, report.sweep)
            if truth is not None:
                from lessmap.evaluation.figures.building import write_consistency_figure

                path = out / "consistency.png"
                figures.append(write_consistency_figure(path, truth, detections))
        markdown = eval_markdown(report, consistency, [path.name for path in figures])
        (out / "eval.md").write_text(markdown, "utf-8")
        written = [out / "eval.json", out / "eval.md", *figures]
        sys.stdout.write("".join(f"wrote {path}\n" for path in written))
    return 0


def _consistency(
    args: argparse.Namespace, params: PartitionParams
) -> tuple[SimTruth, list[Consistency], dict[str, list[Detection]]]:
    """Score LESS-mapping and the first fixed-features baseline on every robot of a sim run.

    Returns:
        The truth, the scores (LESS-mapping first) and each method's detections.
    """
    from lessmap.evaluation.data.simrun import load_truth
    from lessmap.evaluation.scores.consistency import (
        area_detections,
        fixed_feature_detections,
        lessmap_detections,
        score,
    )
    from lessmap.files.frames import read_frames

    if args.tolerance_frames < 0 or not args.door_distance >= 0:
        msg = "--tolerance-frames and --door-distance must not be negative"
        raise ConfigError(msg)
    truth = load_truth(args.file)
    frames = list(read_frames(args.file))
    options = {"tolerance_frames": args.tolerance_frames, "door_distance_m": args.door_distance}
    name = f"lessmap (Ncut≤{params.ncut_min:g}, λ2≤{params.lambda2_min:g})"
    detections = {name: lessmap_detections(frames, params)}
    for limit in args.fixed_features[:1]:
        detections[f"fixed-{limit} features"] = fixed_feature_detections(frames, limit)
    detections["areas"] = area_detections(frames, area_params(partition_settings(args)))
    results = [
        score(truth, found, method=method, **options) for method, found in detections.items()
    ]
    return truth, results, detections


def scale_odometry(dataset: Dataset, scale: float) -> Dataset:
    """Return the data set with its odometry information multiplied by ``scale``."""
    if scale == 1.0:
        return dataset
    problem = replace(dataset.problem, odo_information=dataset.problem.odo_information * scale)
    note = f"odometry information scaled by {scale:g}"
    return replace(dataset, problem=problem, note="; ".join(filter(None, [dataset.note, note])))


def run_plot(args: argparse.Namespace) -> int:
    """Write the PNG figures of one LESS-mapping run (and of the sweep unless --no-sweep).

    With ``--area-graph`` draw that file's fleet graph, or ``--robot``'s, instead.
    """
    if args.area_graph is not None:
        if args.file is not None:
            msg = "give FILE or --area-graph, not both"
            raise ConfigError(msg)
        return _plot_area_graph(args.area_graph, args.robot, args.out)
    if args.file is None:
        msg = "give FILE (frames) or --area-graph G.json"
        raise ConfigError(msg)
    from lessmap.evaluation.data.dataset import load_frames
    from lessmap.evaluation.data.segmentation import run_lessmap
    from lessmap.evaluation.data.simrun import choose_robot, load_for_eval
    from lessmap.evaluation.figures.segmentation import write_plots
    from lessmap.evaluation.scores.infoloss import landmark_information
    from lessmap.evaluation.studies.sweep import sweep

    params = _params(args)
    ncuts, lams = _grid(args)
    if ncuts and lams:
        dataset = load_for_eval(args.file, args.robot)  # the sweep's e needs H
        frames = dataset.frames
        info = landmark_information(dataset.problem)
        main = {(params.ncut_min, params.lambda2_min): run_lessmap(frames, params)}
        rows = sweep(frames, info, params, ncuts, lams, jobs=args.jobs, known=main)
        run = next(iter(main.values()))
    else:
        frames = load_frames(args.file, choose_robot(args.file, args.robot))[1]
        run, rows = run_lessmap(frames, params), []
    _warn_if_sparse("plot", args.file, frames)
    written = write_plots(args.out, frames, run, rows)
    sys.stdout.write("".join(f"wrote {path}\n" for path in written))
    return 0


def _plot_area_graph(source: Path, robot: str | None, out: Path) -> int:
    """Draw an area-graph file's fleet graph, or one robot's."""
    from lessmap.evaluation.figures.area_graph import draw_area_graph
    from lessmap.files.area_graph import read_graph_file

    robots, fleet = read_graph_file(source)
    if robot is None:
        graph: AreaGraph | FleetGraph = fleet
        title = f"fleet areas of {source.name} ({len(robots)} robots)"
    elif robot in robots:
        graph, title = robots[robot], f"areas of robot {robot} ({source.name})"
    else:
        msg = f"{source}: no robot {robot!r}; it has {', '.join(sorted(robots)) or 'none'}"
        raise ConfigError(msg)
    if out.is_dir():
        msg = f"--out {out} is a folder; with --area-graph give the figure's file (FIG.png)"
        raise ConfigError(msg)
    written = draw_area_graph(out, graph, title)
    sys.stdout.write(f"wrote {written}\n")
    return 0


def configure_eval(ev: argparse.ArgumentParser) -> None:
    """Define ``lessmap eval`` (run by ``run_eval``)."""
    ev.description = (
        "Segment FILE.frames.jsonl with LESS-mapping and with the baselines "
        "(fixed features per submap, fixed frames per submap, no partition) and print the "
        "information-loss ratio e of each: the share of the landmark information matrix "
        "(poses marginalized) that the partition drops. Needs <name>.edges.jsonl and "
        "<name>.odometry.jsonl next to the frames file."
    )
    _add_common(ev)
    ev.add_argument(
        "-o", "--out", type=Path, metavar="DIR", help="also write DIR/eval.json, eval.md"
    )
    ev.add_argument("--plots", action="store_true", help="also write the PNGs into --out DIR")
    ev.add_argument(
        "--fixed-features",
        type=int,
        nargs="+",
        default=[50, 60],
        metavar="N",
        help="fixed-features baselines (default: 50 60, Estrada et al.)",
    )
    ev.add_argument(
        "--fixed-frames",
        type=int,
        metavar="K",
        help="frames per submap of the fixed-frames baseline (default: as many "
        "submaps as LESS-mapping makes)",
    )
    ev.add_argument(
        "--odometry-scale",
        type=float,
        default=1.0,
        metavar="S",
        help="multiply the odometry information by S before forming H (default 1)",
    )
    truth = ev.add_argument_group("consistency (simulated runs: <name>.truth.jsonl next to FILE)")
    truth.add_argument(
        "--tolerance-frames",
        type=int,
        default=DEFAULT_TOLERANCE_FRAMES,
        metavar="K",
        help=f"matching window, frames (default {DEFAULT_TOLERANCE_FRAMES})",
    )
    truth.add_argument(
        "--door-distance",
        type=float,
        default=DEFAULT_DOOR_DISTANCE_M,
        metavar="M",
        help=f"'near a door' radius, metres (default {DEFAULT_DOOR_DISTANCE_M:g})",
    )
    ev.add_argument(
        "--anchor-information",
        type=float,
        default=DEFAULT_ANCHOR_INFORMATION,
        help="prior on the first pose that fixes the gauge (default 1e9)",
    )


def configure_plot(plot: argparse.ArgumentParser) -> None:
    """Define ``lessmap plot`` (run by ``run_plot``)."""
    plot.description = (
        "Segment FILE.frames.jsonl with LESS-mapping and write trajectory.png, "
        "ncut_lambda2.png, similarity.png and (unless --no-sweep, which also drops the need "
        "for the edges and odometry files) sweep.png into DIR. With --area-graph OUT.json "
        "instead of FILE (written by lessmap segment --method areas --area-graph), draw "
        "that file's fleet area graph (--robot R: robot R's) into the figure --out names: "
        "nodes sized by frames, edges as wide as their passages, both labelled."
    )
    _add_common(plot, file_optional=True)
    plot.add_argument(
        "-o",
        "--out",
        type=Path,
        metavar="DIR",
        required=True,
        help="output folder (with --area-graph: the figure's file, e.g. FIG.png)",
    )
    plot.add_argument(
        "--area-graph",
        type=Path,
        metavar="G.json",
        help="draw this area-graph file (written by lessmap segment --area-graph or lessmap "
        "areas --out) instead of FILE",
    )

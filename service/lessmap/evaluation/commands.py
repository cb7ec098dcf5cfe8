"""The ``lessmap eval`` and ``lessmap plot`` subcommands (wired into ``lessmap.cli``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lessmap.core import PROFILES, PartitionParams, SeedMode
from lessmap.errors import ConfigError
from lessmap.evaluation.infoloss import DEFAULT_ANCHOR_INFORMATION


def _add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", type=Path, help="frames file (.frames.jsonl)")
    parser.add_argument("--robot", help="robot to evaluate (needed when the file has several)")
    group = parser.add_argument_group("partitioning (LESS-mapping Eq. 4)")
    group.add_argument(
        "--profile",
        choices=sorted(PROFILES),
        default="laser",
        help="threshold profile (default: laser = Ncut 0.25, λ2 0.2)",
    )
    group.add_argument("--ncut-min", type=float, help="override the profile's Ncut threshold")
    group.add_argument("--lambda2-min", type=float, help="override the profile's λ2 threshold")
    group.add_argument(
        "--seed-mode",
        choices=[m.value for m in SeedMode],
        default=SeedMode.SEED.value,
        help="CovGraph after a transition",
    )
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
    sweep.add_argument("--jobs", type=int, default=1, help="worker processes for the sweep")


def _params(args: argparse.Namespace) -> PartitionParams:
    overrides: dict[str, object] = {"seed_mode": SeedMode(args.seed_mode)}
    if args.ncut_min is not None:
        overrides["ncut_min"] = args.ncut_min
    if args.lambda2_min is not None:
        overrides["lambda2_min"] = args.lambda2_min
    if args.jobs < 1:
        msg = f"--jobs must be at least 1, got {args.jobs}"
        raise ConfigError(msg)
    return PartitionParams.from_profile(args.profile, **overrides)


def _grid(args: argparse.Namespace) -> tuple[list[float], list[float]]:
    if args.no_sweep:
        return [], []
    return list(args.sweep_ncut), list(args.sweep_lambda2)


def run_eval(args: argparse.Namespace) -> int:
    """Print e of LESS-mapping and the baselines, and the sweep; write files with --out."""
    from lessmap.evaluation.dataset import load_dataset
    from lessmap.evaluation.report import evaluate

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
    dataset = load_dataset(args.file, args.robot)
    ncuts, lams = _grid(args)
    report = evaluate(
        dataset,
        params,
        feature_limits=args.fixed_features,
        frames_per_submap=args.fixed_frames,
        ncut_values=ncuts,
        lambda2_values=lams,
        jobs=args.jobs,
        anchor_information=args.anchor_information,
    )
    sys.stdout.write(report.to_text())
    if args.out is not None:
        out: Path = args.out
        out.mkdir(parents=True, exist_ok=True)
        (out / "eval.json").write_text(json.dumps(report.as_dict(), indent=1) + "\n", "utf-8")
        (out / "eval.md").write_text(report.to_markdown(), "utf-8")
        written = [out / "eval.json", out / "eval.md"]
        if args.plots:
            from lessmap.evaluation.plots import write_plots

            written += write_plots(out, dataset.frames, report.lessmap, report.sweep)
        sys.stdout.write("".join(f"wrote {path}\n" for path in written))
    return 0


def run_plot(args: argparse.Namespace) -> int:
    """Write the PNG figures of one LESS-mapping run (and of the sweep unless --no-sweep)."""
    from lessmap.evaluation.dataset import load_dataset, load_frames
    from lessmap.evaluation.infoloss import landmark_information
    from lessmap.evaluation.plots import write_plots
    from lessmap.evaluation.segmentation import run_lessmap
    from lessmap.evaluation.sweep import sweep

    params = _params(args)
    ncuts, lams = _grid(args)
    if ncuts and lams:
        dataset = load_dataset(args.file, args.robot)  # the sweep's e needs edges + odometry
        frames = dataset.frames
        info = landmark_information(dataset.problem)
        main = {(params.ncut_min, params.lambda2_min): run_lessmap(frames, params)}
        rows = sweep(frames, info, params, ncuts, lams, jobs=args.jobs, known=main)
        run = next(iter(main.values()))
    else:
        frames = load_frames(args.file, args.robot)[1]
        run, rows = run_lessmap(frames, params), []
    written = write_plots(args.out, frames, run, rows)
    sys.stdout.write("".join(f"wrote {path}\n" for path in written))
    return 0


def add_commands(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``eval`` and ``plot`` subcommands to the ``lessmap`` parser."""
    ev = commands.add_parser(
        "eval",
        help="information loss e (Eq. 5) of LESS-mapping vs. baselines, and a threshold sweep",
        description="Segment FILE.frames.jsonl with LESS-mapping and with the baselines "
        "(fixed features per submap, fixed frames per submap, no partition) and print the "
        "information-loss ratio e of each: the share of the landmark information matrix "
        "(poses marginalized) that the partition drops. Needs <name>.edges.jsonl and "
        "<name>.odometry.jsonl next to the frames file.",
    )
    _add_common(ev)
    ev.add_argument("--out", type=Path, metavar="DIR", help="also write DIR/eval.json, eval.md")
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
        "--anchor-information",
        type=float,
        default=DEFAULT_ANCHOR_INFORMATION,
        help="prior on the first pose that fixes the gauge (default 1e9)",
    )
    ev.set_defaults(run=run_eval)

    plot = commands.add_parser(
        "plot",
        help="PNG figures: trajectory by submap, Ncut/λ2 over frames, reordered W, sweep",
        description="Segment FILE.frames.jsonl with LESS-mapping and write trajectory.png, "
        "ncut_lambda2.png, similarity.png and (unless --no-sweep, which also drops the need "
        "for the edges and odometry files) sweep.png into DIR.",
    )
    _add_common(plot)
    plot.add_argument("--out", type=Path, metavar="DIR", required=True, help="output folder")
    plot.set_defaults(run=run_plot)

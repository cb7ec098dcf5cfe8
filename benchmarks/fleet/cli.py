"""The command line of the fleet load benchmark: its options, the spec they give, one run or
the knee search (``python -m benchmarks.fleet_load``).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from benchmarks.fleet.knee import _compare_workers, find_knee
from benchmarks.fleet.loadgen import LoadSpec
from benchmarks.fleet.orchestrate import run_load
from benchmarks.fleet.process import pyspy_path
from benchmarks.fleet.report import KNEE_HEADER, _json, format_report, knee_row

_KNEE_ROBOTS = (25, 50, 100, 150, 200, 300, 400, 600, 800, 1000)


def add_fleet_options(parser: argparse.ArgumentParser) -> None:
    """Add the options of the fleet load benchmark (shared with benchmarks/fleet_load.py)."""
    parser.add_argument("--robots", type=int, default=200, help="robots N (default 200)")
    parser.add_argument("--rate", type=float, default=10.0, help="frames/s per robot (10)")
    parser.add_argument("--features", type=int, default=20, help="mean features per frame (20)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of load (60)")
    parser.add_argument("--seed", type=int, default=0, help="simulator seed (0)")
    parser.add_argument(
        "--generators",
        type=int,
        default=2,
        choices=[1, 2, 3, 4],
        help="load generator processes (default 2)",
    )
    parser.add_argument("--rooms", type=int, default=12, help="rooms per building (12)")
    parser.add_argument("--shards", type=int, help="service shards (default: its own, 1)")
    parser.add_argument(
        "--workers",
        dest="serve_workers",
        type=int,
        default=1,
        help="worker processes of each `lessmap serve --workers N` (default 1); each worker "
        "is reported as an instance",
    )
    parser.add_argument(
        "--compare-workers",
        type=lambda t: [int(v) for v in t.split(",")],
        metavar="N,M",
        help="with --find-knee: find the knee for each of these --workers counts in one run "
        "and print them side by side",
    )
    parser.add_argument(
        "--instances",
        type=int,
        default=1,
        help="service instances (default 1: one instance, its own router); N > 1: a "
        "`lessmap router` and N instances joined to it as clients, sharing the fleet's "
        "partitions; the report gives each instance's frames received next to its robots'",
    )
    parser.add_argument(
        "--kill-one-after",
        type=float,
        metavar="S",
        help="with --instances >= 2: kill -9 one instance S seconds into the load and report "
        "how long until each of its robots is served by a survivor, and the frames lost",
    )
    parser.add_argument(
        "--max-batch-frames",
        type=int,
        help="service coalescing bound (default: its own; 1 = decide per frame)",
    )
    parser.add_argument(
        "--batch-linger-ms",
        type=float,
        help="service wait for more frames after a wake-up (default: its own; 0 = off)",
    )
    parser.add_argument(
        "--memory-only",
        action="store_true",
        help="run the service without session checkpoints (default: checkpoints on)",
    )
    parser.add_argument(
        "--pin-generators",
        action="store_true",
        help="run the load generators on the last CPU only (default: anywhere); the service "
        "keeps every CPU",
    )
    parser.add_argument(
        "--method",
        choices=["paper", "areas"],
        help="segmentation method of the service's sessions (default: its own, areas)",
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument(
        "--find-knee",
        action="store_true",
        help="run increasing N at --rate x --features and report the largest N "
        "with 0 lost, p99 service latency ≤ 250 ms and flat RSS",
    )
    parser.add_argument(
        "--knee-robots",
        type=lambda t: [int(v) for v in t.split(",")],
        default=list(_KNEE_ROBOTS),
        help="fleet sizes for --find-knee, comma separated",
    )
    parser.add_argument(
        "--knee-duration",
        type=float,
        default=40.0,
        help="seconds per --find-knee step (40: shorter steps end before the CovGraphs of "
        "200+ robots have grown, and the RSS rule then fails on warm-up)",
    )
    parser.add_argument(
        "--profile",
        type=Path,
        metavar="FILE",
        help="py-spy record the service after warm-up: raw collapsed stacks "
        "plus FILE.summary.txt, or a flame graph if FILE ends in .svg",
    )
    parser.add_argument(
        "--profile-duration", type=float, default=20.0, help="seconds of profile (20)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def spec_from_args(args: argparse.Namespace) -> LoadSpec:
    """Build the load spec from parsed options."""
    return LoadSpec(
        robots=args.robots,
        rate_hz=args.rate,
        features=args.features,
        duration_s=args.duration,
        seed=args.seed,
        generators=args.generators,
        rooms=args.rooms,
        shards=args.shards,
        serve_workers=args.serve_workers,
        instances=args.instances,
        kill_after_s=args.kill_one_after,
        max_batch_frames=args.max_batch_frames,
        batch_linger_ms=args.batch_linger_ms,
        memory_only=args.memory_only,
        pin_generators=args.pin_generators,
        method=args.method,
    )


def run_fleet(args: argparse.Namespace) -> int:
    """Run the fleet load benchmark; exit code 0 when the bar is met, 2 when missed."""
    log = None if args.quiet else sys.stderr
    spec = spec_from_args(args)
    if args.find_knee and args.compare_workers:
        return _compare_workers(spec, args, log)
    if args.find_knee:
        if log is not None:
            log.write(KNEE_HEADER + "\n")
        knee, reports = find_knee(
            replace(spec, duration_s=args.knee_duration), args.knee_robots, log=log
        )
        if args.json:
            sys.stdout.write(
                _json({"knee_robots": knee, "runs": [r.as_dict() for r in reports]}) + "\n"
            )
        else:
            table = "\n".join([KNEE_HEADER, *(knee_row(r) for r in reports)])
            found = f"{knee} robots" if knee is not None else "none of these sizes met the bar"
            sys.stdout.write(
                f"{table}\nknee: {found} at {spec.rate_hz:g} Hz × {spec.features} features\n"
            )
        return 0
    if args.profile is not None and pyspy_path() is None:
        sys.stderr.write("fleet_load: --profile needs py-spy (pip install py-spy)\n")
        return 2
    report = run_load(spec, profile=args.profile, profile_duration_s=args.profile_duration, log=log)
    if args.json:
        sys.stdout.write(_json(report.as_dict()) + "\n")
    else:
        sys.stdout.write(format_report(report))
    return 0 if report.passes() else 2

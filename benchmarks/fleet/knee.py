"""The knee of the fleet load benchmark: increasing fleet sizes until one misses the bar.

``find_knee`` runs ``run_load`` at each size; ``_compare_workers`` finds the knee of each
``--workers`` count of ``--compare-workers`` and prints them side by side.
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace
from typing import IO, TYPE_CHECKING

from benchmarks.fleet.orchestrate import run_load
from benchmarks.fleet.process import load_average
from benchmarks.fleet.report import KNEE_HEADER, LoadReport, _json, knee_row

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable, Sequence

    from benchmarks.fleet.loadgen import LoadSpec


def find_knee(
    base: LoadSpec,
    robots: Sequence[int],
    log: IO[str] | None = None,
    meets: Callable[[LoadReport], bool] = LoadReport.passes,
) -> tuple[int | None, list[LoadReport]]:
    """Run increasing fleet sizes until one misses the bar; return the largest that met it."""
    reports: list[LoadReport] = []
    knee: int | None = None
    for count in robots:
        report = run_load(replace(base, robots=count), log=log)
        reports.append(report)
        if log is not None:
            log.write(knee_row(report) + "\n")
            log.flush()
        if not meets(report):
            break
        knee = count
    return knee, reports


def _compare_workers(spec: LoadSpec, args: argparse.Namespace, log: IO[str] | None) -> int:
    """The knee of each ``--workers`` count of ``--compare-workers``, side by side."""
    found: list[tuple[int, int | None, list[LoadReport]]] = []
    for count in args.compare_workers:
        if log is not None:
            log.write(f"--workers {count}\n{KNEE_HEADER}\n")
        knee, reports = find_knee(
            replace(spec, duration_s=args.knee_duration, serve_workers=count),
            args.knee_robots,
            log=log,
            meets=LoadReport.meets_latency_bar,
        )
        found.append((count, knee, reports))
    if args.json:
        runs = {
            str(count): {"knee_robots": knee, "runs": [r.as_dict() for r in reports]}
            for count, knee, reports in found
        }
        sys.stdout.write(_json({"workers": runs, "load_average_end": load_average()}) + "\n")
        return 0
    lines = []
    for count, _knee, reports in found:
        lines += [f"--workers {count}", KNEE_HEADER, *(knee_row(r) for r in reports)]
    knees = ", ".join(
        f"{knee if knee is not None else 'none'} robots with --workers {count}"
        for count, knee, _ in found
    )
    one_min, five_min, _ = load_average()
    lines.append(
        f"knee (0 lost, p99 receipt -> decision <= 250 ms; the pass column adds flat RSS) "
        f"at {spec.rate_hz:g} Hz x {spec.features} features: {knees} "
        f"(load average at the end {one_min:.2f} / {five_min:.2f}, {os.cpu_count()} CPUs)"
    )
    sys.stdout.write("\n".join(lines) + "\n")
    return 0

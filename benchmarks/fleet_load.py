"""Fleet load benchmark: N robots × R Hz × F features against a real ``lessmap serve``.

Run from the repository root (docs/BENCHMARKS.md explains every figure):

    python -m benchmarks.fleet_load --robots 200 --rate 10 --features 20 --duration 60
    python -m benchmarks.fleet_load --find-knee
    python -m benchmarks.fleet_load --robots 150 --duration 40 --profile profile.txt
    python -m benchmarks.fleet_load --robots 200 --duration 30 --instances 4
    python -m benchmarks.fleet_load --robots 200 --instances 2 --kill-one-after 10

The machinery lives in ``benchmarks/fleet/``, outside every wheel. Importable:
``run_load(LoadSpec(...))`` returns a ``LoadReport``; ``format_report`` prints it.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from benchmarks.fleet.cli import add_fleet_options, run_fleet
from benchmarks.fleet.knee import find_knee
from benchmarks.fleet.orchestrate import (
    LoadReport,
    LoadSpec,
    format_report,
    run_load,
    simulated_streams,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    "LoadReport",
    "LoadSpec",
    "find_knee",
    "format_report",
    "main",
    "run_load",
    "simulated_streams",
]


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the options and run the benchmark; 0 when the bar is met, 2 when missed."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.fleet_load",
        description="Start `lessmap serve` on a free loopback port (or, with --instances N > 1, "
        "a `lessmap router` and N instances joined to it) and 1-4 load generator processes "
        "that publish simulated robots in real time; print frames offered, applied and lost, "
        "latencies, service CPU and RSS, each instance's frames received next to its robots' "
        "frames, and an in-process baseline of the core on the same streams. Exit code 2 when "
        "the bar is missed: 0 lost, p99 service latency ≤ 250 ms, flat RSS.",
    )
    add_fleet_options(parser)
    return run_fleet(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())

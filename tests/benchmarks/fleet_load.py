"""Fleet load benchmark: N robots × R Hz × F features against a real ``lessmap serve``.

Run from the repository root (docs/BENCHMARKS.md explains every figure):

    python tests/benchmarks/fleet_load.py --robots 200 --rate 10 --features 20 --duration 60
    python tests/benchmarks/fleet_load.py --find-knee
    python tests/benchmarks/fleet_load.py --robots 150 --duration 40 --profile profile.txt

The same benchmark is ``lessmap bench fleet``; the machinery lives in ``lessmap.tools.bench``
so the installed command has it too. Importable: ``run_load(LoadSpec(...))`` returns a
``LoadReport``; ``format_report`` prints it.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from lessmap.tools.bench import (
    LoadReport,
    LoadSpec,
    add_fleet_options,
    find_knee,
    format_report,
    run_fleet,
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
        prog="fleet_load.py",
        description="Fleet load benchmark of lessmap serve (same options as `lessmap bench "
        "fleet`).",
    )
    add_fleet_options(parser)
    return run_fleet(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())

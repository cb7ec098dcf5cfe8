"""Statistics of the floor-plan simulator on the benchmark maps: what a run looks like.

    python -m benchmarks.floorplan_sim [--sensor laser270] [--robots 2] [--seed 0]
        [--folder ../shared/floorplans] [MAP ...]

For each map (default: every ``<map>.png`` with a ``<map>_gt_segmentation.png`` beside it)
runs ``simulate_floorplan`` and prints one Markdown row: rooms, rooms visited, frames, mean
features a frame, metres walked, true room changes per 100 m of path, and the run's time
(wall clock, and the process's CPU time, which a busy machine inflates less).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from lessmap.floorplan.grid import load_grid, room_labels
from lessmap.floorplan.options import PROFILES, FloorplanOptions
from lessmap.floorplan.simulation import simulate_floorplan

FOLDER = Path(__file__).resolve().parents[2] / ".." / "shared" / "floorplans"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maps", nargs="*", help="map names (default: all with ground truth)")
    parser.add_argument("--folder", type=Path, default=FOLDER)
    parser.add_argument("--sensor", choices=list(PROFILES), default="laser270")
    parser.add_argument("--robots", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    names = args.maps or sorted(
        p.name.removesuffix("_gt_segmentation.png")
        for p in args.folder.glob("*_gt_segmentation.png")
    )
    if not names:
        sys.stderr.write(f"no maps with ground truth under {args.folder}\n")
        return 1
    options = FloorplanOptions(sensor=PROFILES[args.sensor], robots=args.robots, seed=args.seed)
    out = sys.stdout
    out.write(f"sensor {args.sensor}, {args.robots} robot(s), seed {args.seed}\n\n")
    out.write(
        "| map | rooms | visited | frames | features/frame | path m | changes/100 m "
        "| time s | CPU s |\n"
    )
    out.write("|---|---|---|---|---|---|---|---|---|\n")
    totals = {"changes": 0, "path": 0.0}
    for name in names:
        started = time.perf_counter()
        cpu = time.process_time()
        grid = load_grid(args.folder / f"{name}.png")
        labels = room_labels(args.folder / f"{name}_gt_segmentation.png")
        run = simulate_floorplan(grid, labels, options)
        took_s = time.perf_counter() - started
        cpu_s = time.process_time() - cpu
        features = np.mean([len(f["features"]) for f in run.frames])
        path_m = sum(run.path_m.values())
        totals["changes"] += len(run.room_changes)
        totals["path"] += path_m
        out.write(
            f"| {name} | {run.rooms} | {len(run.rooms_visited)} | {len(run.frames)} | "
            f"{features:.1f} | {path_m:.0f} | {100.0 * len(run.room_changes) / path_m:.1f} | "
            f"{took_s:.1f} | {cpu_s:.1f} |\n"
        )
        out.flush()
    pooled = 100.0 * totals["changes"] / totals["path"]
    out.write(f"\npooled: {pooled:.1f} true room changes per 100 m\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What one frame's decision costs, its tail included: ``python -m benchmarks.decision_tail``.

Each stream is segmented by each method, one robot at a time, in this process with BLAS on
one thread (as ``lessmap serve``); a frame's cost is the CPU time of its ``apply`` and
``decide``. Printed per stream and method: the mean, p50, p99, p99.9 and max, the graph's
nodes at the costliest frame, and the ratio to the paper's method on the same frames.

Streams: the floor plan this package ships, toured with each sensor (always available),
the benchmark's floor plans named with ``--floorplans`` (read from ``--floorplan-dir``),
and any frames files given with ``--frames`` (the shared data sets, say).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from lessmap.core.segmenter import make_segmenter
from lessmap.files.frames import FrameRow, read_frames
from lessmap.floorplan.example import EXAMPLE_LABELS, EXAMPLE_MAP
from lessmap.floorplan.grid import load_grid, room_labels
from lessmap.floorplan.options import PROFILES, FloorplanOptions, TourOptions
from lessmap.floorplan.simulation import simulate_floorplan

METHODS = ("paper", "areas", "rooms")
SENSORS = ("laser270", "laser360", "sparse", "camera")
SHARED_FLOORPLANS = Path("../shared/floorplans")


@dataclass(frozen=True, slots=True)
class Tail:
    """One method's per-frame CPU on one stream."""

    costs_ms: list[float]
    nodes_at_max: int

    def quantile(self, q: float) -> float:
        """The q-quantile of the frames' costs (nearest rank)."""
        return float(np.quantile(self.costs_ms, q, method="inverted_cdf"))


def floorplan_stream(
    grid_path: Path, labels_path: Path, sensor: str, max_frames: int, rate_hz: float
) -> list[FrameRow]:
    """Two robots touring a floor plan with one sensor, seed 0."""
    grid = load_grid(grid_path)
    labels = room_labels(labels_path, grid.resolution_m)
    options = FloorplanOptions(
        sensor=PROFILES[sensor],
        robots=2,
        seed=0,
        tour=TourOptions(rate_hz=rate_hz, speed_m_per_frame=1.0 / rate_hz, max_frames=max_frames),
    )
    run = simulate_floorplan(grid, labels, options)
    return [
        FrameRow(f["robot"], f["seq"], f["stamp"], tuple(f["features"]), None) for f in run.frames
    ]


def measure(frames: list[FrameRow], method: str) -> Tail:
    """Segment every robot's frames with one method, timing each frame."""
    costs: list[float] = []
    worst, nodes_at_worst = -1.0, 0
    by_robot: dict[str, list[FrameRow]] = {}
    for frame in frames:
        by_robot.setdefault(frame.robot, []).append(frame)
    for rows in by_robot.values():
        segmenter = make_segmenter(method)
        for frame in rows:
            started = time.thread_time()
            segmenter.apply(frame.seq, frame.stamp_s, frame.features)
            segmenter.decide()
            cost = 1000.0 * (time.thread_time() - started)
            costs.append(cost)
            if cost > worst:
                worst, nodes_at_worst = cost, segmenter.node_count
    return Tail(costs, nodes_at_worst)


def report(name: str, frames: list[FrameRow], methods: tuple[str, ...]) -> list[str]:
    """Markdown rows of one stream, every method beside the paper's."""
    tails = {method: measure(frames, method) for method in methods}
    base = tails.get("paper")
    features = statistics.mean(len(f.features) for f in frames) if frames else 0.0
    lines = []
    for method, tail in tails.items():
        mean = statistics.mean(tail.costs_ms)
        p99 = tail.quantile(0.99)
        ratio = "–"
        if base is not None:
            ratio = f"{mean / statistics.mean(base.costs_ms):.2f} / {p99 / base.quantile(0.99):.2f}"
        lines.append(
            f"| {name} | {features:.0f} | {method} | {len(tail.costs_ms)} | {1000 * mean:.0f} | "
            f"{tail.quantile(0.5):.2f} | {p99:.2f} | {tail.quantile(0.999):.2f} | "
            f"{max(tail.costs_ms):.2f} | {tail.nodes_at_max} | {ratio} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    """Print the table; exit 1 on a missing input."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--sensors", nargs="+", default=list(SENSORS), choices=SENSORS)
    parser.add_argument("--floorplans", nargs="*", default=[], help="benchmark map names")
    parser.add_argument("--floorplan-dir", type=Path, default=SHARED_FLOORPLANS)
    parser.add_argument("--frames", nargs="*", type=Path, default=[], help="frames files")
    parser.add_argument("--max-frames", type=int, default=1500, help="frames a robot at most")
    parser.add_argument("--rate", type=float, default=10.0, help="frames a second (floor plans)")
    args = parser.parse_args(argv)
    maps = [("example", EXAMPLE_MAP, EXAMPLE_LABELS)]
    for name in args.floorplans:
        grid = args.floorplan_dir / f"{name}.png"
        labels = args.floorplan_dir / f"{name}_gt_segmentation.png"
        if not grid.is_file() or not labels.is_file():
            print(f"decision_tail: no map {name} in {args.floorplan_dir}", file=sys.stderr)
            return 1
        maps.append((name, grid, labels))
    print(
        "| stream | features a frame | method | frames | mean µs | p50 ms | p99 ms | p99.9 ms "
        "| max ms | nodes at max | mean / p99 against paper |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    with threadpool_limits(limits=1):
        for name, grid, labels in maps:
            for sensor in args.sensors:
                frames = floorplan_stream(grid, labels, sensor, args.max_frames, args.rate)
                for line in report(f"{name} {sensor}", frames, tuple(args.methods)):
                    print(line, flush=True)
        for path in args.frames:
            try:
                frames = list(read_frames(path))
            except (OSError, ValueError) as exc:
                print(f"decision_tail: {path}: {exc}", file=sys.stderr)
                return 1
            for line in report(path.name, frames, tuple(args.methods)):
                print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Camera robots: cost per frame and quality of the areas method with and without sampling.

``python -m benchmarks.camera``: camera-like streams are simulated on the benchmark's floor
plans (``../shared/floorplans``; the ``camera`` sensor, denser with more layers, ``--streams``).
Offline (BLAS on one thread, as ``serve``), each stream runs through the area tracker twice,
unreduced (``max_features_kept`` 0) and with the default sampling: the cost of each frame (its
add and settle, as ``lessmap segment`` calls them) as median and p99, and the sampled run's
transitions against the unreduced run's (a boundary matches within ``--tolerance`` frames
and twice that: recall and precision), and both runs' recall of the true room changes. The
data sets in ``../shared/datasets`` (all under the cap) must give identical transitions. The
1-minute load average is printed before and after (the host may be shared).

Live (unless ``--no-live``): a fresh ``lessmap serve`` with default settings (its state in
a temporary folder) takes the first stream at ``--rate`` frames/s; its /metrics give the
share of frames decided within 20 ms and 100 ms of their receipt, and its transitions are
compared with the offline sampled run's. Every process is stopped by its PID.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from lessmap.core.areas.tracker import AreaParams, AreaTracker
from lessmap.files.frames import FrameRow, read_frames
from lessmap.floorplan.grid import load_grid, room_labels
from lessmap.floorplan.options import PROFILES, FloorplanOptions, TourOptions
from lessmap.floorplan.simulation import simulate_floorplan

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO / ".." / "shared"
DEFAULT_CAP = AreaParams().max_features_kept


@dataclass(slots=True)
class Stream:
    """One robot's frames, and where the true room changes are (empty for a data set)."""

    name: str
    frames: list[FrameRow]
    room_changes: list[int]


@dataclass(slots=True)
class Run:
    """One pass of the area tracker over a stream."""

    cap: int
    costs_ms: list[float]
    boundaries: list[int]
    records: list[tuple[int, int, int | None]]  # (boundary_seq, area, revisit_of)
    kept_mean: float
    rate: float


def simulated(map_name: str, layers: int, frames: int, seed: int, rate_hz: float) -> Stream:
    """A camera robot touring one floor plan (``layers`` heights of wall texture)."""
    folder = SHARED / "floorplans"
    grid = load_grid(folder / f"{map_name}.png")
    labels = room_labels(folder / f"{map_name}_gt_segmentation.png", grid.resolution_m)
    sensor = replace(PROFILES["camera"], layers=layers)
    options = FloorplanOptions(
        sensor=sensor,
        robots=1,
        seed=seed,
        tour=TourOptions(rate_hz=rate_hz, max_frames=frames),
    )
    run = simulate_floorplan(grid, labels, options)
    rows = [
        FrameRow(f["robot"], f["seq"], f["stamp"], tuple(f["features"]), None) for f in run.frames
    ]
    return Stream(f"{map_name}/{layers}", rows, [c.seq for c in run.room_changes])


def track(stream: Stream, cap: int) -> Run:
    """Run one area tracker over a stream's frames (one robot), timing each frame."""
    tracker = AreaTracker(replace(AreaParams(), max_features_kept=cap))
    costs: list[float] = []
    records: list[tuple[int, int, int | None]] = []
    kept = 0
    for frame in stream.frames:
        started = time.perf_counter()
        tracker.add(frame.seq, frame.stamp_s, frame.features)
        change = tracker.settle()
        costs.append(1000.0 * (time.perf_counter() - started))
        kept += len(tracker.frames[-1][1]) if tracker.frames else 0
        if change is not None:
            records.append((change.transition.boundary_seq, change.area, change.revisit_of))
    return Run(
        cap=cap,
        costs_ms=costs,
        boundaries=[r[0] for r in records],
        records=records,
        kept_mean=kept / max(1, len(stream.frames)),
        rate=tracker.sampler.rate,
    )


def matched(reference: list[int], found: list[int], tolerance: int) -> int:
    """Pairs of boundaries within ``tolerance`` frames, each used once (nearest first)."""
    pairs = sorted(
        (abs(a - b), i, j)
        for i, a in enumerate(reference)
        for j, b in enumerate(found)
        if abs(a - b) <= tolerance
    )
    used_a: set[int] = set()
    used_b: set[int] = set()
    for _, i, j in pairs:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
    return len(used_a)


def pct(values: list[float], q: float) -> float:
    """The q-quantile (nearest rank) of values."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


def ratio(a: float, b: float) -> float:
    """a / b, NaN when b is 0."""
    return a / b if b else float("nan")


def offline(stream: Stream, tolerance: int) -> tuple[Run, Run, dict[str, Any]]:
    """The unreduced and the sampled run of one stream, side by side."""
    full, sampled = track(stream, 0), track(stream, DEFAULT_CAP)
    hits = matched(full.boundaries, sampled.boundaries, tolerance)
    wide = matched(full.boundaries, sampled.boundaries, 2 * tolerance)
    truth = stream.room_changes
    figures = {
        "stream": stream.name,
        "frames": len(stream.frames),
        "features": statistics.fmean(len(f.features) for f in stream.frames),
        "max_features": max(len(f.features) for f in stream.frames),
        "kept": sampled.kept_mean,
        "rate": sampled.rate,
        "full_p50": pct(full.costs_ms, 0.5),
        "full_p99": pct(full.costs_ms, 0.99),
        "p50": pct(sampled.costs_ms, 0.5),
        "p99": pct(sampled.costs_ms, 0.99),
        "full_changes": len(full.boundaries),
        "changes": len(sampled.boundaries),
        "recall": ratio(hits, len(full.boundaries)) if full.boundaries else 1.0,
        "precision": ratio(hits, len(sampled.boundaries)) if sampled.boundaries else 1.0,
        "recall_wide": ratio(wide, len(full.boundaries)) if full.boundaries else 1.0,
        "precision_wide": ratio(wide, len(sampled.boundaries)) if sampled.boundaries else 1.0,
        "identical": full.records == sampled.records,
        "true_changes": len(truth),
        "full_truth_recall": ratio(matched(truth, full.boundaries, 2 * tolerance), len(truth)),
        "truth_recall": ratio(matched(truth, sampled.boundaries, 2 * tolerance), len(truth)),
    }
    return full, sampled, figures


def print_offline(rows: list[dict[str, Any]], tolerance: int) -> None:
    """The offline table, unreduced beside sampled, with ratios."""
    print(
        f"offline, areas method, ms a frame (add + settle); cap {DEFAULT_CAP}; R/P: the "
        f"unreduced run's boundaries matched within {tolerance} and {2 * tolerance} frames; "
        f"truth: true room changes matched within {2 * tolerance} frames, unreduced/sampled"
    )
    print(
        f"{'stream':<16} {'frames':>6} {'feat':>4} {'max':>5} {'kept':>4} "
        f"{'full p50':>8} {'p99':>6} {'samp p50':>8} {'p99':>5} {'x p50':>5} {'x p99':>5} "
        f"{'full':>4} {'samp':>4} {'R':>4} {'P':>4} {'R2':>4} {'P2':>4} {'true':>4} {'truth':>9} "
        "same"
    )
    for r in rows:
        print(
            f"{r['stream']:<16} {r['frames']:>6} {r['features']:>4.0f} {r['max_features']:>5} "
            f"{r['kept']:>4.0f} {r['full_p50']:>8.1f} {r['full_p99']:>6.1f} {r['p50']:>8.1f} "
            f"{r['p99']:>5.1f} {ratio(r['full_p50'], r['p50']):>5.1f} "
            f"{ratio(r['full_p99'], r['p99']):>5.1f} {r['full_changes']:>4} {r['changes']:>4} "
            f"{r['recall']:>4.2f} {r['precision']:>4.2f} {r['recall_wide']:>4.2f} "
            f"{r['precision_wide']:>4.2f} {r['true_changes']:>4} "
            f"{r['full_truth_recall']:>4.2f}/{r['truth_recall']:<4.2f} {r['identical']}"
        )


def datasets(names: list[str], tolerance: int) -> list[dict[str, Any]]:
    """The shared data sets, one stream per robot: identical transitions under the cap."""
    rows = []
    for name in names:
        path = SHARED / "datasets" / f"{name}.frames.jsonl"
        if not path.exists():
            print(f"{path}: absent, skipped", file=sys.stderr)
            continue
        robots: dict[str, list[FrameRow]] = {}
        for frame in read_frames(path):
            robots.setdefault(frame.robot, []).append(frame)
        for robot, frames in robots.items():
            rows.append(offline(Stream(f"{name}:{robot}", frames, []), tolerance)[2])
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the offline comparison, then the live run; print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument(
        "--streams",
        nargs="+",
        default=["office_a:18", "lab_f_scan:24", "office_b:12"],
        metavar="MAP:LAYERS",
        help="floor plans and the heights of wall texture the camera sees there (the camera "
        "sensor's is 12, ~500 features a frame; 18-24 give 700-1,000); the first goes live",
    )
    parser.add_argument("--frames", type=int, default=1000, help="frames per stream")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rate", type=float, default=10.0, help="frames/s (stamps, live)")
    parser.add_argument("--tolerance", type=int, default=5, help="frames")
    parser.add_argument(
        "--datasets", nargs="*", default=["dlr", "mrclam6", "mrclam1_w1s"], help="shared sets"
    )
    parser.add_argument("--no-live", action="store_true", help="skip the live serve run")
    parser.add_argument("--json", type=Path, help="also write the figures to this file")
    args = parser.parse_args(argv)
    threadpool_limits(1)  # BLAS on one thread, as lessmap serve runs it
    load_before = os.getloadavg()[0]
    streams = []
    for spec in args.streams:
        name, _, layers = spec.partition(":")
        streams.append(simulated(name, int(layers or 12), args.frames, args.seed, args.rate))
    rows = [offline(stream, args.tolerance)[2] for stream in streams]
    rows += datasets(args.datasets, args.tolerance)
    print_offline(rows, args.tolerance)
    figures: dict[str, Any] = {"offline": rows}
    if not args.no_live and streams:
        from benchmarks.camera_live import live, print_live

        sampled = track(streams[0], DEFAULT_CAP)
        result = live(streams[0].frames, args.rate, sampled.records)
        print_live(streams[0].name, args.rate, result)
        figures["live"] = result
    print(f"load average (1 min) {load_before:.1f} -> {os.getloadavg()[0]:.1f}")
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What durable sessions cost per frame: one session table with and without the store.

    python -m benchmarks.checkpoint_cost [--dataset ../shared/datasets/dlr.frames.jsonl]

Feeds a frames file (one session per robot, decide at every frame) through a
``SessionTable`` three ways in the same run, alternating: memory-only (the baseline), with
the SQLite store at the default checkpoint setting (every 100 frames / 5 s), and
checkpointing after every frame (the worst case). Prints the worker thread's CPU per frame
(median of the repeats) and the ratios to the baseline; the store's writer runs on its own
thread and is reported apart.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap.core import PartitionParams
from lessmap.core.segmenter import Method
from lessmap.files.frames import read_frames
from lessmap.runtime.sessions import (
    DurabilityPolicy,
    Identity,
    Segmenting,
    SessionLimits,
    SessionTable,
    commit_checkpoints,
)
from lessmap.runtime.store import CheckpointStore
from lessmap_schemas.messages import Frame

if TYPE_CHECKING:
    from collections.abc import Sequence


def run(frames: list[tuple[str, Frame]], every: int | None) -> tuple[float, float]:
    """Return (worker CPU seconds, writer seconds) of one pass."""
    with tempfile.TemporaryDirectory() as folder:
        store = CheckpointStore(None if every is None else Path(folder))
        store.open()
        table = SessionTable(
            # The paper: the method of the figures in docs/BENCHMARKS.md.
            Segmenting(params=PartitionParams.from_profile("laser"), method=Method.PAPER),
            SessionLimits(
                max_sessions=1000, max_nodes=20_000, max_batch_frames=1, idle_timeout_s=3600.0
            ),
            identity=Identity(instance="bench"),
            store=store,
            durability=DurabilityPolicy(every_frames=every or 1, interval_s=5.0),
        )
        started = time.thread_time()
        for robot, frame in frames:
            # As the service: the outcome's checkpoints are saved once it is published.
            commit_checkpoints(
                table.handle_batch([("bench", robot, frame)], time.monotonic()), store
            )
        commit_checkpoints(table.close_all("shutdown"), store)
        worker = time.thread_time() - started
        store.close()
        return worker, store.write_seconds


def main(argv: Sequence[str] | None = None) -> int:
    """Run the comparison and print it."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.checkpoint_cost")
    parser.add_argument("--dataset", type=Path, default=Path("../shared/datasets/dlr.frames.jsonl"))
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    frames = [
        (
            row.robot,
            Frame(session="s", seq=row.seq, stamp_s=row.stamp_s, features=list(row.features)),
        )
        for row in read_frames(args.dataset)
    ]
    modes = {"memory-only": None, "store, every 100": 100, "store, every frame": 1}
    results: dict[str, list[tuple[float, float]]] = {name: [] for name in modes}
    for _ in range(args.repeats):
        for name, every in modes.items():
            results[name].append(run(frames, every))
    base = statistics.median(w for w, _ in results["memory-only"]) / len(frames)
    out = sys.stdout
    out.write(f"{args.dataset.name}: {len(frames)} frames, {args.repeats} repeats, median\n")
    for name, values in results.items():
        worker = statistics.median(w for w, _ in values) / len(frames)
        writer = statistics.median(s for _, s in values) / len(frames)
        out.write(
            f"  {name:20s} worker {1e6 * worker:7.1f} µs/frame ({worker / base:4.2f}x)"
            f"   writer {1e6 * writer:6.1f} µs/frame\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

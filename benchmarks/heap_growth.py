"""Where a worker's Python heap grows as its sessions age, in one process (``tracemalloc``).

Run from the repository root (docs/BENCHMARKS.md, "Long runs"):

    python -m benchmarks.heap_growth --robots 20 --seconds 1800

The live fleet benchmark sees the process's RSS, which mixes the Python heap, Zenoh's
memory (its transition caches are in Rust) and the allocator's. This one feeds
``service_overhead``'s worker (a real ``Shard``, ``SessionTable``, ``Outbox`` on a Zenoh
peer session and a ``CheckpointStore`` in a temporary folder, the service's defaults) the
fleet's frames as fast as it takes them, and snapshots the traced Python heap after a
third, two thirds and all of the stream (each after the store's writer caught up and a
collection). It prints the heap at each snapshot, per robot, and the files whose
allocations grew most between the last two.
"""

from __future__ import annotations

import argparse
import gc
import sys
import tempfile
import tracemalloc
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh

from benchmarks.service_overhead import as_received, build_worker, fleet_frames, local_peer
from lessmap.core.segmenter import DEFAULT_METHOD, Method

if TYPE_CHECKING:
    from collections.abc import Sequence

_PER_SWEEP = 40  # frames handed on at once, as a receiver sweep does under load


def _short(filename: str) -> str:
    """A file's name from its package on (``lessmap/core/...``, ``numpy/...``)."""
    for root in ("site-packages/", "/service/", "/schemas/", "/lib/python3"):
        if root in filename:
            return filename.rsplit(root, 1)[1]
    return filename


def main(argv: Sequence[str] | None = None) -> int:
    """Print the traced heap at thirds of the stream and where it grew last."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.heap_growth")
    parser.add_argument("--robots", type=int, default=20, help="robots (20)")
    parser.add_argument("--seconds", type=float, default=1800.0, help="seconds of frames (1800)")
    parser.add_argument("--rate", type=float, default=10.0, help="frames/s per robot (10)")
    parser.add_argument("--method", choices=[m.value for m in Method], default=DEFAULT_METHOD)
    parser.add_argument("--transition-cache", type=int, default=64, help="as serve's (64)")
    parser.add_argument("--top", type=int, default=10, help="files listed (10)")
    args = parser.parse_args(argv)
    if args.robots < 1 or args.seconds <= 0 or args.rate <= 0:
        sys.stderr.write("heap_growth: --robots, --seconds and --rate must be > 0\n")
        return 2
    items = as_received(fleet_frames(args.robots, args.seconds, args.rate))
    thirds = {len(items) // 3: "1/3", 2 * len(items) // 3: "2/3", len(items): "end"}
    snapshots: list[tuple[str, tracemalloc.Snapshot]] = []
    with zenoh.open(local_peer()) as session, tempfile.TemporaryDirectory() as folder:
        worker = build_worker(
            session,
            args.robots,
            Path(folder),
            method=Method(args.method),
            transition_cache=args.transition_cache,
        )
        tracemalloc.start()
        fed = 0
        for at in range(0, len(items), _PER_SWEEP):
            chunk = items[at : at + _PER_SWEEP]
            worker.feed(chunk)
            fed += len(chunk)
            due = [name for mark, name in thirds.items() if at < mark <= fed]
            for name in due:
                worker.store.flush()
                gc.collect()
                snapshots.append((name, tracemalloc.take_snapshot()))
                traced = tracemalloc.get_traced_memory()[0] / 1024
                print(
                    f"{name:>4}: {fed} frames, heap {traced:,.0f} KiB, "
                    f"{traced / args.robots:,.1f} KiB a robot"
                )
        tracemalloc.stop()
        worker.store.close()
        worker.outbox.close()
    (_, before), (_, after) = snapshots[-2], snapshots[-1]
    print(f"grew most from {snapshots[-2][0]} to {snapshots[-1][0]} (KiB, by file):")
    for stat in after.compare_to(before, "filename")[: args.top]:
        print(f"{stat.size_diff / 1024:9.1f}  {_short(stat.traceback[0].filename)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The service's own CPU per frame beside the core's, in one process, interleaved.

Run from the repository root (docs/BENCHMARKS.md, "Per-frame CPU"):

    python -m benchmarks.service_overhead --robots 100 --seconds 20 --repeats 3
    python -m benchmarks.service_overhead --robots 100 --seconds 20 --compare-ref main

The fleet benchmark (``fleet_load``) measures the whole process under real load, but on a
shared machine its core baseline runs at another moment than the service, and their ratio
moves with the load. This one runs both on the same frames in the same process, one after
the other, ``--repeats`` times, and times each with the thread's CPU clock:

- ``core``: one segmenter of ``--method`` per robot (the service's default unless told),
  ``apply`` and ``decide`` per frame, robots interleaved frame by frame (the fleet
  benchmark's baseline, with as many robots);
- ``worker``: a real ``Shard`` (its worker's loop run in this thread) with a real
  ``SessionTable`` and an ``Outbox`` on a Zenoh peer session, with the service's defaults:
  work budgets (so edges are counted) and a ``CheckpointStore`` in a temporary folder
  (a checkpoint per 100 frames of a session; the store's writer thread and Zenoh's threads
  are counted too: process CPU), fed the encoded frames as the receiver hands them on
  (``offer_many``, one batch per ``--sweep-ms`` of the fleet's frames), deciding at every
  frame as at 200 robots unloaded (``--memory-only``: no store);
- ``receive``: the receiver's sweep of real Zenoh channels (samples put on a local session),
  per sample.

It prints µs per frame and the ratios worker / core and (worker + receive) / core. Zenoh's
own threads (network, routing) are not in it: the fleet benchmark shows them.
``--compare-ref REF`` runs all of it on REF's code and on this tree (``benchmarks.reference``)
and prints both with the ratios REF / this tree.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh
from threadpoolctl import threadpool_limits

import lessmap
from benchmarks import reference
from benchmarks.fleet.loadgen import LoadSpec, robot_name, simulated_streams
from lessmap.config.settings import ServiceSettings
from lessmap.core import PartitionParams
from lessmap.core.segmenter import DEFAULT_METHOD, Method, make_segmenter
from lessmap.runtime.metrics import ServiceMetrics
from lessmap.runtime.outbox import EgressPolicy, Outbox
from lessmap.runtime.receiver import Receiver
from lessmap.runtime.sessions import (
    DurabilityPolicy,
    Identity,
    Segmenting,
    SessionLimits,
    SessionTable,
)
from lessmap.runtime.shard import Inbound, Shard, ShardPolicy
from lessmap.runtime.store import CheckpointStore
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.limits import DEFAULT_LIMITS
from lessmap_schemas.messages import Frame

if TYPE_CHECKING:
    from collections.abc import Sequence

FLEET = "bench"
_SPACING_M = 0.352  # landmark spacing that gives 20 features per frame (fleet_load's calibration)


def fleet_frames(robots: int, seconds: float, rate_hz: float) -> list[tuple[int, Frame]]:
    """The fleet's frames in publishing order: (robot index, frame), robots interleaved."""
    spec = LoadSpec(robots=robots, generators=1, duration_s=seconds, rate_hz=rate_hz)
    streams = simulated_streams(spec, 0, _SPACING_M)
    out: list[tuple[int, Frame]] = []
    for k in range(max(len(s) for s in streams)):
        for robot, stream in enumerate(streams):
            if k < len(stream):
                frame = Frame(session="s1", seq=k, stamp_s=k / rate_hz, features=stream[k])
                out.append((robot, frame))
    return out


def as_received(frames: Sequence[tuple[int, Frame]]) -> list[Inbound]:
    """The frames encoded and addressed as the receiver hands them to a shard."""
    return [
        Inbound(0.0, keys.frames(FLEET, robot_name(robot)), encode(frame))
        for robot, frame in frames
    ]


def local_peer() -> zenoh.Config:
    """A Zenoh peer that finds no one: the outbox's puts stay in this process."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def time_core(frames: Sequence[tuple[int, Frame]], robots: int, method: Method) -> float:
    """Thread CPU seconds of the core alone on the frames: apply and decide every frame."""
    params = PartitionParams.from_profile("laser")
    segmenters = [make_segmenter(method, params) for _ in range(robots)]
    started = time.process_time()
    for robot, frame in frames:
        segmenter = segmenters[robot]
        segmenter.apply(frame.seq, frame.stamp_s, frame.features)
        segmenter.decide()
    return time.process_time() - started


@dataclass(slots=True)
class Worker:
    """A shard's worker as the service builds it (``build_worker``): fed in this thread."""

    shard: Shard
    outbox: Outbox
    store: CheckpointStore

    def feed(self, items: Sequence[Inbound]) -> None:
        """Hand the items on as the receiver does, and run the worker's loop until idle."""
        refused = self.shard.offer_many(list(items))
        assert not refused
        self.shard._collect()
        while self.shard._lanes:
            self.shard._round()


def build_worker(
    session: zenoh.Session,
    robots: int,
    folder: Path | None,
    *,
    method: Method,
    transition_cache: int = 16,
) -> Worker:
    """A real ``Shard`` with its ``SessionTable``, ``Outbox`` and store (``folder`` None: none)."""
    fields = ServiceSettings.model_fields
    every, interval = (
        fields[f].default for f in ("checkpoint_every_frames", "checkpoint_interval_s")
    )
    max_pairs, max_edges = (
        fields[f].default for f in ("max_pairs_per_frame", "max_edges_per_session")
    )
    store = CheckpointStore(folder)
    store.open()
    outbox = Outbox(
        session,
        ServiceMetrics(),
        instance="bench",
        policy=EgressPolicy(
            transition_cache=transition_cache,
            max_publishers=robots,
            error_rate_per_s=10.0,
            error_burst=10,
        ),
        store=store,
    )
    table = SessionTable(
        Segmenting(params=PartitionParams.from_profile("laser"), method=method),
        SessionLimits(
            max_sessions=robots,
            max_nodes=100_000,
            max_batch_frames=256,
            idle_timeout_s=3600.0,
            max_pairs_per_frame=max_pairs,
            max_edges_per_session=max_edges,
        ),
        identity=Identity(instance="bench"),
        store=None if folder is None else store,
        durability=DurabilityPolicy(every_frames=every, interval_s=interval),
    )
    shard = Shard(
        0,
        table,
        outbox,
        limits=DEFAULT_LIMITS,
        policy=ShardPolicy(queue_depth=1 << 20, queue_bytes=1 << 30),
    )
    return Worker(shard, outbox, store)


def time_worker(
    session: zenoh.Session,
    items: Sequence[Inbound],
    robots: int,
    per_sweep: int,
    *,
    memory_only: bool,
    method: Method,
) -> float:
    """CPU seconds of a shard's worker loop on the encoded frames (module docstring)."""
    with tempfile.TemporaryDirectory() as folder:
        worker = build_worker(session, robots, None if memory_only else Path(folder), method=method)
        started = time.process_time()
        for at in range(0, len(items), per_sweep):
            worker.feed(items[at : at + per_sweep])
        worker.store.close()  # the writer thread's work is counted: it is the service's too
        spent = time.process_time() - started
        applied = worker.outbox.frames_applied
        worker.outbox.close()
    assert applied == len(items), f"{applied} of {len(items)} frames applied"
    return spent


def time_receive(session: zenoh.Session, items: Sequence[Inbound], per_sweep: int) -> float:
    """Thread CPU seconds of the receiver's sweeps over real channels, per sample batch."""
    metrics = ServiceMetrics()
    table = SessionTable(
        Segmenting(params=PartitionParams.from_profile("laser"), method=Method.PAPER),
        SessionLimits(max_sessions=1, max_nodes=10, max_batch_frames=1, idle_timeout_s=60.0),
        identity=Identity(instance="bench"),
    )
    outbox = Outbox(
        session,
        metrics,
        instance="bench",
        policy=EgressPolicy(
            transition_cache=1,
            max_publishers=1,
            error_rate_per_s=1.0,
            error_burst=1,
        ),
    )
    shard = Shard(
        0,
        table,
        outbox,
        limits=DEFAULT_LIMITS,
        policy=ShardPolicy(queue_depth=1 << 20, queue_bytes=1 << 30),
    )
    receiver = Receiver(
        [shard], metrics, max_payload_bytes=1 << 20, queue_depth=1 << 20, owned=lambda _p: True
    )
    partitions = range(256)
    subs = {
        p: session.declare_subscriber(keys.frames_of_partition(p), receiver.channel())
        for p in partitions
    }
    receiver.watch(subs)
    spent = 0.0
    try:
        for at in range(0, len(items), per_sweep):
            for item in items[at : at + per_sweep]:
                session.put(item.key, item.payload)
            started = time.thread_time()
            found = receiver.sweep()
            spent += time.thread_time() - started
            assert found == len(items[at : at + per_sweep]), found
    finally:
        for sub in subs.values():
            sub.undeclare()
        outbox.close()
    return spent


def main(argv: Sequence[str] | None = None) -> int:
    """Run the comparison and print µs per frame and ratios (or JSON)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.service_overhead")
    parser.add_argument("--robots", type=int, default=100, help="robots (100)")
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds of frames (20)")
    parser.add_argument("--rate", type=float, default=10.0, help="frames/s per robot (10)")
    parser.add_argument(
        "--sweep-ms",
        type=float,
        default=10.0,
        help="frames handed on per sweep: the fleet's "
        "frames in this many ms at 200 robots x rate (10)",
    )
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repeats (3)")
    parser.add_argument(
        "--memory-only",
        action="store_true",
        help="no checkpoint store (lessmap serve --memory-only)",
    )
    parser.add_argument(
        "--method",
        choices=[m.value for m in Method],
        default=DEFAULT_METHOD.value,
        help=f"segmentation method of the sessions and the core ({DEFAULT_METHOD.value})",
    )
    parser.add_argument(
        "--compare-ref",
        metavar="REF",
        help="run this benchmark on the code of git REF and on this tree, alternately, "
        "--repeats times each (child processes), and print both with the ratios",
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if args.compare_ref:
        try:
            return compare_ref(args)
        except reference.RefRunError as exc:
            sys.stderr.write(f"service_overhead: {exc}\n")
            return 2
    method = Method(args.method)
    frames = fleet_frames(args.robots, args.seconds, args.rate)
    items = as_received(frames)
    per_sweep = max(1, round(200 * args.rate * args.sweep_ms / 1000))
    runs: dict[str, list[float]] = {"core": [], "worker": [], "receive": []}
    with zenoh.open(local_peer()) as session, threadpool_limits(limits=1):
        for _ in range(args.repeats):
            runs["core"].append(time_core(frames, args.robots, method))
            runs["worker"].append(
                time_worker(
                    session,
                    items,
                    args.robots,
                    per_sweep,
                    memory_only=args.memory_only,
                    method=method,
                )
            )
            runs["receive"].append(time_receive(session, items, per_sweep))
    us = {name: 1e6 * statistics.median(values) / len(frames) for name, values in runs.items()}
    load = f"{os.getloadavg()[0]:.2f}"
    result = {
        "frames": len(frames),
        "robots": args.robots,
        "per_sweep": per_sweep,
        "us_per_frame": us,
        "runs_s": runs,
        "worker_over_core": us["worker"] / us["core"],
        "service_over_core": (us["worker"] + us["receive"]) / us["core"],
        "load_after": load,
        "method": method.value,
        "code": str(Path(lessmap.__file__).resolve().parents[1]),
    }
    if args.json:
        sys.stdout.write(json.dumps(result) + "\n")
        return 0
    sys.stdout.write(
        f"{len(frames)} frames of {args.robots} robots, {per_sweep} per sweep, medians of "
        f"{args.repeats} (process CPU; receiver: its thread's), load average {load}"
        f"{', memory-only' if args.memory_only else ', checkpoints on'}\n"
        f"  core observe          {us['core']:7.1f} µs/frame\n"
        f"  shard worker          {us['worker']:7.1f} µs/frame  "
        f"= {result['worker_over_core']:.2f}× core\n"
        f"  receiver sweep        {us['receive']:7.1f} µs/frame\n"
        f"  worker + receiver     {us['worker'] + us['receive']:7.1f} µs/frame  "
        f"= {result['service_over_core']:.2f}× core\n"
    )
    return 0


_PARTS = ("core", "worker", "receive")


def compare_ref(args: argparse.Namespace) -> int:
    """Alternate child runs on ``--compare-ref``'s code and this tree's; print both."""
    child = [
        *("--robots", str(args.robots), "--seconds", str(args.seconds)),
        *("--rate", str(args.rate), "--sweep-ms", str(args.sweep_ms)),
        *("--method", args.method, "--repeats", "1"),
        *(["--memory-only"] if args.memory_only else []),
    ]
    runs: dict[str, list[dict[str, float]]] = {"ref": [], "this": []}
    code: dict[str, str] = {}  # where each side's lessmap was imported from
    commit = reference.describe(args.compare_ref)
    with reference.checkout(args.compare_ref) as tree:
        for _ in range(args.repeats):
            for side, root in (("ref", tree), ("this", reference.REPO)):
                found = reference.run_child(root, "service_overhead", child)
                runs[side].append({**found["us_per_frame"], "frames": found["frames"]})
                code[side] = found["code"]
    us = {
        side: {part: statistics.median(run[part] for run in found) for part in _PARTS}
        for side, found in runs.items()
    }
    for side in us:
        us[side]["worker+receive"] = us[side]["worker"] + us[side]["receive"]
    ratios = {part: us["ref"][part] / us["this"][part] for part in us["this"]}
    load = f"{os.getloadavg()[0]:.2f}"
    if args.json:
        result = {"ref": args.compare_ref, "commit": commit, "us_per_frame": us}
        result |= {"ref_over_this": ratios, "runs": runs, "code": code, "load_after": load}
        sys.stdout.write(json.dumps(result) + "\n")
        return 0
    frames = runs["this"][0]["frames"]
    sys.stdout.write(
        f"{frames:.0f} frames of {args.robots} robots, method {args.method}, medians of "
        f"{args.repeats} alternating child runs, load average {load}\n"
        f"  µs per frame          {args.compare_ref} ({commit})   this tree   ref / this\n"
    )
    for part, ratio in ratios.items():
        sys.stdout.write(
            f"  {part:<20}  {us['ref'][part]:14.1f}  {us['this'][part]:10.1f}   {ratio:9.2f}×\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

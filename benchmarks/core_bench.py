"""Per-frame CPU of the core beside eigen-solver baselines on the same graphs.

    python -m benchmarks.core_bench                     # n = 50 ... 3200, visual, memory
    python -m benchmarks.core_bench --quick             # n = 50, 200, 800; no 10k session
    python -m benchmarks.core_bench --sizes 400,1600 --frames 40 --profile 1600
    python -m benchmarks.core_bench --sizes 400,1600,3200 --no-visual --no-memory --worst 5
    python -m benchmarks.core_bench --store-ab          # visual: dense vs sparse store

Run from the repository root. Everything runs in this process on one thread (BLAS pinned to
one thread with threadpoolctl, as ``lessmap serve`` does), except the 10,000-node memory
session, which runs in a subprocess so that its peak RSS is its own.

Streams (seeded, synthetic; ``lessmap.sim`` is far too slow to make rooms of thousands of
landmarks). Landmarks are tracked: each track lasts 10-30 frames, then a new one starts on a
landmark of the current room not being tracked (re-detection keeps the ID).

- **room chain, size n**: a robot walks rooms 0 -> 1 -> 2, each with n landmarks of its own,
  min(F, 0.7 n) tracks per frame (F = ``--features``, 40 by default). At a door, half the
  tracks move to the new room in one frame and the rest in the next. After each door the
  robot looks around: 3n·20/F frames are applied without a decision (the service's
  coalescing path) and decided once, unmeasured, so the CovGraph holds about 95 % of the
  room; then every frame is measured (``observe``: apply + decide): the two door frames and
  one more per door, and the frames inside each room. The CovGraph thus sits at about n
  nodes (the table prints the median size the measured decisions saw).
- **visual**: stereo-tracking-like. Rooms of 1,200 landmarks, 550 tracks per frame; from 10
  frames before a room's end, new tracks start on the next room. Every frame after the
  first 15 is measured.

Per measured frame, lessmap's CPU is ``time.process_time`` around ``apply`` + ``decide``
(default parameters of the profile: laser for the room chain, stereo for the visual stream;
``always_solve`` off, so dense graphs use the Cholesky certificate). A second, unmeasured
replay of the same stream hands each decision's W (the CSR matrix the decision saw) to the
baselines, timed from W to the Fiedler pair:

- ``eigh``: ``scipy.linalg.eigh`` of the dense normalized Laplacian I - D^-1/2 W D^-1/2,
  two smallest pairs; every frame up to 400 nodes, at most ``--eigh-samples`` evenly spaced
  frames up to ``--eigh-max`` nodes (1,600 by default), not above;
- ``ARPACK warm``: ``scipy.sparse.linalg.eigsh`` on S = D^-1/2 W D^-1/2 (CSR), k = 2,
  which = LA, tol = 1e-10, ``v0`` = the previous decision's Fiedler vector (mapped by feature
  ID; new features 0).

MRPT: the script prints whether a Debian MRPT Python binding (python3-mrpt) is importable;
its partitioner is not driven yet (no binding was installed to develop the column against).
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import json
import pstats
import statistics
import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import linalg, sparse
from scipy.sparse.linalg import ArpackNoConvergence, eigsh
from threadpoolctl import threadpool_limits

from benchmarks.core_memory import bytes_per_node_and_edge, memory_child, run_memory_child
from benchmarks.core_streams import Stream, room_chain, visual
from lessmap.core import Partitioner, PartitionParams, Transition
from lessmap.core.paper import covgraph

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from lessmap.core.paper.submaps import Evaluation

SIZES = (50, 100, 200, 400, 800, 1600, 3200)
QUICK_SIZES = (50, 200, 800)
ARPACK_TOL = 1e-10
TARGETS_MS = {400: 1.0, 1600: 5.0, 3200: 12.0}  # the median CPU bars


# -- lessmap, timed ------------------------------------------------------------------------


@dataclass(slots=True)
class Timings:
    """Per measured frame: lessmap's CPU (total and decide), nodes, and the baselines."""

    total_ms: list[float] = field(default_factory=list)
    decide_ms: list[float] = field(default_factory=list)
    nodes: list[int] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)  # what settled each measured decision
    edges: list[int] = field(default_factory=list)
    eigh_ms: list[float] = field(default_factory=list)
    eigh_at: list[int] = field(default_factory=list)  # measured frames eigh ran on
    arpack_ms: list[float] = field(default_factory=list)
    eigh_max_nodes: int = 0  # largest graph eigh ran on
    lambda2_gap: float = 0.0  # max |λ2 eigh - λ2 ARPACK| where both ran
    transitions: int = 0


def params_of(stream: Stream, **overrides: Any) -> PartitionParams:
    """The default parameters of the stream's profile."""
    return PartitionParams.from_profile(stream.profile, **overrides)


def time_lessmap(stream: Stream, params: PartitionParams, timings: Timings) -> None:
    """Feed the stream to a fresh partitioner; time apply + decide of each measured frame."""
    partitioner = Partitioner(params)
    clock = time.process_time
    for seq, (frame, measured) in enumerate(zip(stream.frames, stream.measured, strict=True)):
        if not measured:
            partitioner.apply(seq, float(seq), frame)
            continue
        if partitioner.pending_frames:
            partitioner.decide()  # the look-around's one coalesced decision, unmeasured
        started = clock()
        partitioner.apply(seq, float(seq), frame)
        applied = clock()
        partitioner.decide()
        ended = clock()
        timings.total_ms.append(1e3 * (ended - started))
        timings.decide_ms.append(1e3 * (ended - applied))
        evaluation = partitioner.last_evaluation
        timings.nodes.append(evaluation.nodes if evaluation is not None else 0)
        timings.kinds.append(_kind(evaluation, seq))
    timings.transitions = partitioner.transitions


def _kind(evaluation: Evaluation | None, seq: int) -> str:
    """What settled the decision of frame ``seq``: a transition, a solve, or a proof of λ2."""
    if evaluation is None or evaluation.seq != seq:
        return "none"
    if evaluation.transition:
        return "transition"
    if evaluation.lambda2_above is not None:
        return "proven"  # the carried floor, or a fresh Cholesky certificate
    return "solve" if evaluation.nodes >= 2 else "none"


def worst(name: str, t: Timings, count: int) -> str:
    """The ``count`` most expensive measured frames and what each decision ran."""
    order = sorted(range(len(t.total_ms)), key=lambda i: -t.total_ms[i])[:count]
    listed = ", ".join(f"{t.total_ms[i]:.2f} ms ({t.kinds[i]}, {t.nodes[i]} nodes)" for i in order)
    tally = ", ".join(f"{kind} {t.kinds.count(kind)}" for kind in sorted(set(t.kinds)))
    return f"  worst of {name}: {listed}; decisions: {tally}"


def decisions(stream: Stream, params: PartitionParams, *, exact: bool) -> list[tuple[object, ...]]:
    """Every decision on the stream (same schedule as the benchmark) and every transition.

    ``exact``: the reference path, LAPACK on a dense matrix at every decision
    (``always_solve``, no dense size limit), against which the default path is compared.
    """
    if exact:
        params = params_of(stream, dense_max_nodes=10**6)
    partitioner = Partitioner(params, always_solve=exact)
    found: list[tuple[object, ...]] = []
    for seq, (frame, measured) in enumerate(zip(stream.frames, stream.measured, strict=True)):
        if measured and partitioner.pending_frames:
            found.append(_decision(partitioner, partitioner.decide()))
        partitioner.apply(seq, float(seq), frame)
        if measured:
            found.append(_decision(partitioner, partitioner.decide()))
    return found


def _decision(partitioner: Partitioner, transition: Transition | None) -> tuple[object, ...]:
    evaluation = partitioner.last_evaluation
    assert evaluation is not None
    outcome: tuple[object, ...] = (evaluation.seq, evaluation.nodes, evaluation.components)
    outcome += (evaluation.transition,)
    if transition is not None:
        t = transition
        outcome += (t.boundary_seq, t.reason, t.closed, t.opened, t.boundary_features)
    return outcome


def store_ab(stream: Stream, params: PartitionParams | None = None) -> str:
    """The stream fed to two partitioners frame by frame, alternately first: one may hold a
    dense graph above ``dense_max_nodes`` in the dense store, the other keeps the sparse
    store there (``DENSE_STORE_MAX_NODES`` = 0 while it steps). Both see the same load;
    their transitions and evaluations are compared as they are made."""
    caps = {"dense store": covgraph.DENSE_STORE_MAX_NODES, "sparse store": 0}
    params = params_of(stream) if params is None else params
    partitioners = {name: Partitioner(params) for name in caps}
    spent: dict[str, list[float]] = {name: [] for name in caps}
    same = True
    clock = time.process_time
    try:
        for seq, (frame, measured) in enumerate(zip(stream.frames, stream.measured, strict=True)):
            outcomes = {}
            for name in sorted(caps, reverse=seq % 2 == 1):
                covgraph.DENSE_STORE_MAX_NODES = caps[name]
                partitioner = partitioners[name]
                started = clock()
                partitioner.apply(seq, float(seq), frame)
                transition = partitioner.decide()
                if measured:
                    spent[name].append(1e3 * (clock() - started))
                outcomes[name] = (transition, partitioner.last_evaluation)
            same &= outcomes["dense store"] == outcomes["sparse store"]
    finally:
        covgraph.DENSE_STORE_MAX_NODES = caps["dense store"]
    figures = "; ".join(
        f"{name}: median {_median(ms):.1f} ms, mean {statistics.fmean(ms):.1f} ms"
        for name, ms in spent.items()
    )
    return f"{stream.name}, {len(spent['dense store'])} frames: {figures}; same decisions: {same}"


# -- baselines on the same graphs ------------------------------------------------------------


def time_baselines(
    stream: Stream, params: PartitionParams, timings: Timings, *, eigh_max: int, eigh_samples: int
) -> None:
    """Replay the stream (unmeasured) and time the baselines on each measured decision's W."""
    partitioner = Partitioner(params)
    measured_at = [i for i, m in enumerate(stream.measured) if m]
    step = -(-len(measured_at) // max(1, eigh_samples))  # ceil: at most eigh_samples frames
    sampled = set(measured_at[step // 2 :: step])
    previous: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None
    index = -1  # of the measured frame, as in Timings.total_ms
    for seq, (frame, measured) in enumerate(zip(stream.frames, stream.measured, strict=True)):
        if not measured:
            partitioner.apply(seq, float(seq), frame)
            continue
        index += 1
        if partitioner.pending_frames:
            partitioner.decide()
        partitioner.apply(seq, float(seq), frame)
        graph = partitioner.graph
        if graph.node_count >= 2:
            w = graph.covrate()
            ids = graph.feature_ids.copy()
            timings.edges.append(w.nnz // 2)
            n = w.shape[0]
            lambda_eigh = None
            if n <= 400 or (n <= eigh_max and seq in sampled):
                result = eigh_baseline(w)
                if result is not None:
                    timings.eigh_ms.append(result[0])
                    timings.eigh_at.append(index)
                    lambda_eigh = result[1]
                    timings.eigh_max_nodes = max(timings.eigh_max_nodes, n)
            arpack = arpack_warm_baseline(w, ids, previous)
            if arpack is not None:
                elapsed_ms, lambda2, u2 = arpack
                timings.arpack_ms.append(elapsed_ms)
                previous = (ids, u2)
                if lambda_eigh is not None:
                    gap = abs(lambda_eigh - lambda2)
                    timings.lambda2_gap = max(timings.lambda2_gap, gap)
        partitioner.decide()


def eigh_baseline(w: sparse.csr_array) -> tuple[float, float] | None:
    """Dense LAPACK: (ms, λ2) of I - D^-1/2 W D^-1/2, or None when a node has no edge."""
    started = time.process_time()
    dense = w.toarray()
    degrees = dense.sum(axis=1)
    if degrees.min() <= 0.0:
        return None
    inv_sqrt = 1.0 / np.sqrt(degrees)
    lsym = np.eye(dense.shape[0]) - inv_sqrt[:, None] * dense * inv_sqrt[None, :]
    values = linalg.eigh(lsym, subset_by_index=[0, 1], eigvals_only=False)[0]
    return 1e3 * (time.process_time() - started), float(values[1])


def arpack_warm_baseline(
    w: sparse.csr_array,
    ids: NDArray[np.int64],
    previous: tuple[NDArray[np.int64], NDArray[np.float64]] | None,
) -> tuple[float, float, NDArray[np.float64]] | None:
    """ARPACK started from the previous Fiedler vector: (ms, λ2, u2), None on isolated nodes."""
    n = w.shape[0]
    v0 = _warm_start(ids, previous)
    started = time.process_time()
    degrees = np.asarray(w.sum(axis=1)).ravel()
    if degrees.min() <= 0.0 or n < 3:
        return None
    inv_sqrt = 1.0 / np.sqrt(degrees)
    scaled = sparse.csr_array(sparse.diags_array(inv_sqrt) @ w @ sparse.diags_array(inv_sqrt))
    try:
        values, vectors = eigsh(scaled, k=2, which="LA", v0=v0, tol=ARPACK_TOL, maxiter=20 * n)
    except ArpackNoConvergence:
        return None
    elapsed = 1e3 * (time.process_time() - started)
    low = int(np.argmin(values))
    return elapsed, 1.0 - float(values[low]), np.asarray(vectors[:, low], dtype=np.float64)


def _warm_start(
    ids: NDArray[np.int64], previous: tuple[NDArray[np.int64], NDArray[np.float64]] | None
) -> NDArray[np.float64]:
    v0 = np.zeros(ids.size, dtype=np.float64)
    if previous is not None:
        old_ids, old_u2 = previous
        order = np.argsort(old_ids)
        pos = np.searchsorted(old_ids[order], ids).clip(0, old_ids.size - 1)
        hit = old_ids[order][pos] == ids
        v0[hit] = old_u2[order][pos[hit]]
    if not np.any(v0):
        v0 = np.random.default_rng(ids.size).standard_normal(ids.size)  # cold, seeded
    return v0


# -- MRPT (optional) -------------------------------------------------------------------------


def mrpt_binding() -> str | None:
    """Name of an importable MRPT Python binding (Debian python3-mrpt), None when absent."""
    import importlib

    for name in ("mrpt.pymrpt", "pymrpt"):
        try:
            importlib.import_module(name)
        except ImportError:
            continue
        return name
    return None


# -- report --------------------------------------------------------------------------------


def _median(values: Sequence[float]) -> float:
    return statistics.median(values) if values else float("nan")


def _p99(values: Sequence[float]) -> float:
    if not values:
        return float("nan")
    return float(np.percentile(np.asarray(values), 99, method="higher"))


HEADER = (
    f"{'stream':<20} {'frames':>6} {'nodes':>6} {'edges':>8} {'med ms':>8} {'p99 ms':>8} "
    f"{'p99/med':>7} {'mean ms':>8} {'decide':>8} {'eigh ms':>9} {'ARPACK w':>9} {'lm/ARPACK':>9} "
    f"{'lm/eigh':>8} {'MRPT':>5} {'trans':>5}"
)


def row(name: str, t: Timings) -> str:
    """One table row (medians in ms over the measured frames)."""
    median, p99 = _median(t.total_ms), _p99(t.total_ms)
    arpack, eigh = _median(t.arpack_ms), _median(t.eigh_ms)
    # eigh is shown only where it ran on graphs of the stream's size (not above --eigh-max),
    # and compared with lessmap on the same frames.
    shown = t.eigh_max_nodes >= 0.9 * _median(t.nodes)
    paired = _median([t.total_ms[i] for i in t.eigh_at])
    eigh_text = f"{eigh:9.2f}" if shown else f"{'-':>9}"
    eigh_ratio = f"{paired / eigh:8.3f}" if shown else f"{'-':>8}"
    return (
        f"{name:<20} {len(t.total_ms):>6} {int(_median(t.nodes)):>6} {int(_median(t.edges)):>8} "
        f"{median:8.3f} {p99:8.3f} {p99 / median:7.2f} {statistics.fmean(t.total_ms):8.3f} "
        f"{_median(t.decide_ms):8.3f} "
        f"{eigh_text} {arpack:9.3f} {median / arpack:9.2f} {eigh_ratio} {'-':>5} "
        f"{t.transitions:>5}"
    )


def measure(
    stream: Stream, *, eigh_max: int, eigh_samples: int, profile: bool = False
) -> tuple[Timings, str]:
    """Time lessmap then the baselines on one stream; optionally profile lessmap's pass."""
    params = params_of(stream)
    timings = Timings()
    profiler = cProfile.Profile() if profile else None
    gc.collect()
    if profiler is not None:
        profiler.enable()
    time_lessmap(stream, params, timings)
    text = ""
    if profiler is not None:
        profiler.disable()
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(14)
        text = out.getvalue()
    time_baselines(stream, params, timings, eigh_max=eigh_max, eigh_samples=eigh_samples)
    return timings, text


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and print the table, the memory figures and the targets."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.core_bench")
    parser.add_argument("--sizes", help="room-chain sizes, comma separated (default 50...3200)")
    parser.add_argument("--frames", type=int, default=60, help="measured frames per size")
    parser.add_argument("--features", type=int, default=40, help="room chain: per frame")
    parser.add_argument("--quick", action="store_true", help="n = 50, 200, 800; 24 frames")
    parser.add_argument("--visual-frames", type=int, default=60, help="frames per visual room")
    parser.add_argument("--visual-alive", type=int, default=550, help="visual: per frame")
    parser.add_argument("--no-visual", action="store_true")
    parser.add_argument("--no-memory", action="store_true", help="skip the memory figures")
    parser.add_argument("--eigh-max", type=int, default=1600, help="largest graph for eigh")
    parser.add_argument("--eigh-samples", type=int, default=8, help="eigh frames above 400")
    parser.add_argument("--profile", type=int, help="print cProfile of lessmap at this size")
    parser.add_argument(
        "--worst", type=int, default=0, help="list each stream's N most expensive frames"
    )
    parser.add_argument(
        "--store-ab",
        action="store_true",
        help="only the visual stream, dense against sparse store frame by frame (one process)",
    )
    parser.add_argument("--memory-child", nargs=3, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        with threadpool_limits(limits=1):
            sys.stdout.write(json.dumps(memory_child(*args.memory_child)) + "\n")
        return 0
    if args.store_ab:
        stream = visual(frames_per_room=args.visual_frames, alive=args.visual_alive)
        with threadpool_limits(limits=1):
            sys.stdout.write(store_ab(stream) + "\n")
        return 0
    if args.sizes:
        sizes = [int(s) for s in args.sizes.split(",")]
    else:
        sizes = list(QUICK_SIZES if args.quick else SIZES)
    frames = 24 if args.quick and args.frames == 60 else args.frames
    visual_frames = 30 if args.quick and args.visual_frames == 60 else args.visual_frames
    out = sys.stdout
    out.write(
        f"core benchmark: per-frame CPU (process_time, 1 BLAS thread), ms; "
        f"room chain {args.features} features/frame, laser; visual stereo\n"
    )
    out.write(HEADER + "\n")
    results: dict[int, Timings] = {}
    profiles: list[str] = []
    with threadpool_limits(limits=1):
        for n in sizes:
            stream = room_chain(n, frames=frames, features=args.features)
            timings, text = measure(
                stream,
                eigh_max=args.eigh_max,
                eigh_samples=args.eigh_samples,
                profile=args.profile == n,
            )
            results[n] = timings
            out.write(row(f"room chain n={n}", timings) + "\n")
            if args.worst:
                out.write(worst(f"n={n}", timings, args.worst) + "\n")
            out.flush()
            if text:
                profiles.append(f"cProfile, lessmap pass, n={n}:\n{text}")
        if not args.no_visual:
            alive = args.visual_alive
            pool = 1200 if alive == 550 else 2 * alive + 100
            stream = visual(frames_per_room=visual_frames, alive=alive, pool=pool)
            timings, _ = measure(stream, eigh_max=args.eigh_max, eigh_samples=args.eigh_samples)
            features = int(_median([f.size for f in stream.frames]))
            out.write(row(f"visual {features}/frame", timings) + "\n")
            if args.worst:
                out.write(worst("visual", timings, args.worst) + "\n")
    binding = mrpt_binding()
    out.write(
        "MRPT: not installed\n"
        if binding is None
        else f"MRPT: binding {binding} importable, but no column is driven yet\n"
    )
    out.write(
        f"eigh: dense LAPACK, every frame up to 400 nodes, {args.eigh_samples} sampled frames "
        f"up to {args.eigh_max}, none above; ARPACK warm: eigsh k=2 LA tol {ARPACK_TOL:g}, "
        f"v0 = previous Fiedler vector\n"
    )
    gaps = [t.lambda2_gap for t in results.values() if t.eigh_ms]
    if gaps:
        out.write(f"max |λ2 eigh - λ2 ARPACK| where both ran: {max(gaps):.1e}\n")
    for text in profiles:
        out.write(text)
    for n, bar in TARGETS_MS.items():
        if n in results:
            t = results[n]
            median, p99 = _median(t.total_ms), _p99(t.total_ms)
            verdict = "met" if median <= bar else "missed"
            out.write(
                f"target n={n}: median {median:.2f} ms vs <= {bar:g} ms: {verdict}; "
                f"p99/median {p99 / median:.2f} (<= 2: {'met' if p99 <= 2 * median else 'missed'})"
            )
            if n == 1600:
                speedup = _median(t.arpack_ms) / median
                out.write(
                    f"; {speedup:.2f}x ARPACK warm (>= 2x: {'met' if speedup >= 2 else 'missed'})"
                )
            out.write("\n")
    if not args.no_memory:
        fit = bytes_per_node_and_edge()
        out.write(
            f"memory (CovGraph after a W refresh, tracemalloc): {fit['per_node']:.0f} B/node, "
            f"{fit['per_edge']:.1f} B/edge; a dense graph of {fit['dense_nodes']:.0f} nodes "
            f"({fit['dense_share']:.0f} % of the pairs are edges, dense store): "
            f"{fit['dense_per_edge']:.1f} B/edge\n"
        )
        if args.quick:
            out.write("10,000-node 5 M-edge session: skipped (--quick)\n")
        else:
            big = run_memory_child(10_000, 5_000_000, 500)
            verdict = "within" if big["peak_rss_mib"] <= 1024 else "over"
            out.write(
                f"session {big['nodes']:.0f} nodes, {big['edges']:.0f} edges "
                f"({big['frames']:.0f} frames of 500 tracked features, pairs merged every 10, "
                f"one decision at the end): peak RSS {big['peak_rss_mib']:.0f} MiB, "
                f"{big['peak_before_decision_mib']:.0f} MiB before the decision, "
                f"{big['base_rss_mib']:.0f} MiB interpreter and imports; {verdict} 1 GiB; "
                f"{big['cpu_s']:.1f} s CPU\n"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

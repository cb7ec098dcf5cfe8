"""The memory figures of the core benchmark: bytes per node and edge, the 10,000-node session.

``memory_child`` runs in a fresh interpreter (``python -m benchmarks.core_bench
--memory-child``, started by ``run_memory_child``) so that its peak RSS is its own.
"""

from __future__ import annotations

import gc
import json
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from lessmap.core import CovGraph, Partitioner, PartitionParams

REPO = Path(__file__).resolve().parents[1]


def _retained(frames: list[list[int]]) -> tuple[int, int, int]:
    """(nodes, edges, bytes tracemalloc sees held) of a CovGraph of ``frames``, W refreshed."""
    gc.collect()
    before = tracemalloc.get_traced_memory()[0]
    graph = CovGraph()
    for seq, frame in enumerate(frames):
        graph.add_frame(seq, frame)
    graph.similarity()  # as after a decision: W's values are held too
    gc.collect()
    held = tracemalloc.get_traced_memory()[0] - before
    return graph.node_count, graph.edge_count, held


def bytes_per_node_and_edge() -> dict[str, float]:
    """Bytes a CovGraph holds per edge (same 2,000 nodes, 0.2 M vs 1 M edges: the sparse
    store), per node (20,000 nodes in pairs: 10,000 edges), and per edge of a dense graph of
    1,100 nodes (the dense store), from tracemalloc (numpy reports its buffers)."""
    rng = np.random.default_rng(11)
    tracemalloc.start()
    try:
        sparse_graph = [rng.choice(2000, size=40, replace=False).tolist() for _ in range(300)]
        dense_graph = [rng.choice(2000, size=120, replace=False).tolist() for _ in range(200)]
        _, e1, b1 = _retained(sparse_graph)
        _, e2, b2 = _retained(dense_graph)
        per_edge = (b2 - b1) / (e2 - e1)
        n3, e3, b3 = _retained([[2 * i, 2 * i + 1] for i in range(10_000)])
        per_node = (b3 - per_edge * e3) / n3
        # A dense graph above 400 nodes (frames of half of 1,100 features: ~88 % of the
        # pairs are edges) is held in the dense store: 24 B per pair, edge or not.
        frames = [sorted(rng.choice(1100, size=550, replace=False).tolist()) for _ in range(7)]
        n4, e4, b4 = _retained(frames)
    finally:
        tracemalloc.stop()
    return {
        "per_edge": per_edge,
        "per_node": per_node,
        "dense_nodes": n4,
        "dense_share": 200.0 * e4 / (n4 * (n4 - 1)),
        "dense_per_edge": (b4 - per_node * n4) / e4,
    }


def memory_child(nodes: int, edges: int, alive: int) -> dict[str, float]:
    """Build one session of ``nodes`` landmarks, ``alive`` tracked at a time, to ``edges``.

    New tracks start on landmarks never seen while there are any (the robot explores), so
    the graph reaches ``nodes``. An exploring walk is a corridor to the partitioner, which
    would split it long before, so frames are only applied; every 10 frames the pending
    pairs are merged (reading ``edge_count`` does what a decision's refresh does first) and
    at the end one decision runs on the whole graph. Returns the size, CPU seconds and the
    peak RSS (VmHWM) with the RSS before the session.
    """
    base_kib = _hwm_kib()
    rng = np.random.default_rng(5)
    pool = rng.choice(10**9, size=nodes, replace=False).astype(np.int64)
    tracks = np.arange(alive)
    ends = rng.integers(1, 31, size=alive)
    unseen = alive  # pool[unseen:] have not been seen yet
    partitioner = Partitioner(PartitionParams.from_profile("stereo"))
    started = time.process_time()
    seq = 0
    while True:
        done = np.flatnonzero(ends <= seq)
        if done.size:
            fresh = min(done.size, nodes - unseen)
            tracks[done[:fresh]] = np.arange(unseen, unseen + fresh)
            unseen += fresh
            if fresh < done.size:
                free = np.setdiff1d(np.arange(nodes), tracks, assume_unique=True)
                tracks[done[fresh:]] = rng.choice(free, size=done.size - fresh, replace=False)
            ends[done] = seq + rng.integers(10, 31, size=done.size)
        partitioner.apply(seq, float(seq), pool[tracks])
        seq += 1
        graph = partitioner.graph
        if seq % 10 == 0 and graph.edge_count >= edges and graph.node_count >= nodes:
            break
    size = {"nodes": graph.node_count, "edges": graph.edge_count}
    before_decision_kib = _hwm_kib()
    partitioner.decide()
    return {
        **size,
        "transitions": partitioner.transitions,
        "peak_before_decision_mib": before_decision_kib / 1024,
        "frames": seq,
        "cpu_s": time.process_time() - started,
        "base_rss_mib": base_kib / 1024,
        "peak_rss_mib": _hwm_kib() / 1024,
    }


def _hwm_kib() -> int:
    # VmHWM, the peak RSS of this process image (ru_maxrss would carry the parent's over
    # fork and exec).
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    return 0


def run_memory_child(nodes: int, edges: int, alive: int) -> dict[str, float]:
    """Run ``memory_child`` in a fresh interpreter; return its JSON answer."""
    command = [sys.executable, "-m", "benchmarks.core_bench", "--memory-child"]
    command += [str(nodes), str(edges), str(alive)]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, check=True)
    answer: dict[str, float] = json.loads(done.stdout.strip().splitlines()[-1])
    return answer

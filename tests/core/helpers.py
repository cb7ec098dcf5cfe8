"""Shared builders and brute-force references for the core tests (no mocks, seeded rngs)."""

from __future__ import annotations

import io
import itertools
import json
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import sparse

from lessmap.core import Partitioner, PartitionerState, Transition
from lessmap.core.paper.framing import unframe

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from types import ModuleType

    from numpy.typing import NDArray

Frames = list[list[int]]

# -- brute-force references ------------------------------------------------------------------


def brute_counts(
    frames: Sequence[Sequence[int]],
) -> tuple[dict[int, int], dict[frozenset[int], int]]:
    """Recount n_i and a_ij with plain sets and dicts."""
    nodes: dict[int, int] = {}
    pairs: dict[frozenset[int], int] = {}
    for frame in frames:
        seen = set(frame)
        for feature in seen:
            nodes[feature] = nodes.get(feature, 0) + 1
        for a, b in itertools.combinations(sorted(seen), 2):
            key = frozenset((a, b))
            pairs[key] = pairs.get(key, 0) + 1
    return nodes, pairs


def brute_covrate(
    ids: Sequence[int], nodes: dict[int, int], pairs: dict[frozenset[int], int]
) -> NDArray[np.float64]:
    """Dense W_ij = a_ij / min(n_i, n_j) in the node order ``ids``."""
    n = len(ids)
    w = np.zeros((n, n), dtype=np.float64)
    for i, a in enumerate(ids):
        for j, b in enumerate(ids):
            if i != j:
                w[i, j] = pairs.get(frozenset((a, b)), 0) / min(nodes[a], nodes[b])
    return w


def brute_ncut(w: NDArray[np.float64], side: Sequence[bool]) -> float:
    """Shi–Malik Ncut by explicit double loops over a dense W."""
    n = w.shape[0]
    cut = sum(float(w[i, j]) for i in range(n) for j in range(n) if side[i] and not side[j])
    assoc_b = sum(float(w[i, j]) for i in range(n) for j in range(n) if side[i])
    assoc_a = sum(float(w[i, j]) for i in range(n) for j in range(n) if not side[i])
    return cut / assoc_a + cut / assoc_b


def as_partition(labels: Sequence[int] | NDArray[np.integer]) -> frozenset[frozenset[int]]:
    """A two-way labelling as a set of sets of node indices (label values irrelevant)."""
    groups: dict[int, set[int]] = {}
    for node, label in enumerate(np.asarray(labels).tolist()):
        groups.setdefault(int(label), set()).add(node)
    return frozenset(frozenset(g) for g in groups.values())


# -- graph builders --------------------------------------------------------------------------


def symmetric(dense: NDArray[np.float64]) -> sparse.csr_array:
    """CSR of the symmetric part of an upper-triangular weight matrix, zero diagonal."""
    upper = np.triu(dense, k=1)
    return sparse.csr_array(upper + upper.T)


def random_connected(rng: np.random.Generator, n: int, density: float) -> sparse.csr_array:
    """A random weighted connected graph: a random spanning path plus random extra edges."""
    dense = np.where(rng.random((n, n)) < density, rng.uniform(0.05, 1.0, (n, n)), 0.0)
    order = rng.permutation(n)
    for a, b in itertools.pairwise(order.tolist()):
        dense[min(a, b), max(a, b)] = rng.uniform(0.05, 1.0)
    return symmetric(dense)


def planted_two_blocks(
    rng: np.random.Generator, n: int, *, degree: int = 8, bridges: int = 3
) -> tuple[sparse.csr_array, NDArray[np.int8]]:
    """Two sparse dense-ish blocks (about ``degree`` strong edges per node) joined by a few
    weak bridges, nodes shuffled. Returns W and the planted labels."""
    labels = (rng.permutation(n) < n // 2).astype(np.int8)
    dense = np.zeros((n, n), dtype=np.float64)
    for block in (0, 1):
        members = np.flatnonzero(labels == block)
        ring = rng.permutation(members)
        for a, b in itertools.pairwise([*ring.tolist(), int(ring[0])]):
            dense[min(a, b), max(a, b)] = rng.uniform(0.6, 1.0)
        for a in members.tolist():
            for b in rng.choice(members, size=degree, replace=False).tolist():
                if a != b:
                    dense[min(a, b), max(a, b)] = rng.uniform(0.6, 1.0)
    left, right = np.flatnonzero(labels == 0), np.flatnonzero(labels == 1)
    for a, b in zip(
        rng.choice(left, bridges).tolist(), rng.choice(right, bridges).tolist(), strict=True
    ):
        dense[min(a, b), max(a, b)] = rng.uniform(0.01, 0.05)
    return symmetric(dense), labels


def two_cliques(size: int, weak: float, order: NDArray[np.int64]) -> sparse.csr_array:
    """Cliques {0..size-1} and {size..2size-1} (weight 1), one edge 0–size of weight ``weak``;
    node k of the result is node ``order[k]`` of that layout."""
    n = 2 * size
    dense = np.zeros((n, n), dtype=np.float64)
    dense[:size, :size] = 1.0
    dense[size:, size:] = 1.0
    np.fill_diagonal(dense, 0.0)
    dense[0, size] = dense[size, 0] = weak
    return sparse.csr_array(dense[np.ix_(order, order)])


# -- frame streams ---------------------------------------------------------------------------


def two_room_frames() -> Frames:
    """Features 0..9 seen together 30 times, a two-frame door, then 10..19 seen 30 times."""
    frames = [list(range(10)) for _ in range(30)]
    frames.append(list(range(5, 15)))  # seq 30: the door, half of each room
    frames.append(list(range(8, 20)))  # seq 31: mostly the second room
    frames += [list(range(10, 20)) for _ in range(30)]
    return frames


TWO_ROOM_DOOR = 30  # first seq of two_room_frames that sees the second room


@dataclass(frozen=True, slots=True)
class Walk:
    """A synthetic walk through rooms in a row."""

    frames: Frames
    rooms: tuple[frozenset[int], ...]  # landmark IDs of each room
    route: tuple[int, ...]  # rooms visited, in order
    doors: tuple[int, ...]  # seq of the first frame of each visit after the first


def room_walk(
    seed: int,
    *,
    rooms: int = 4,
    back: bool = False,
    stay: tuple[int, int] = (30, 45),
    door_frames: int = 1,
    door_share: float = 0.1,
) -> Walk:
    """Walk room 0 -> room R-1 (and back to 0 when ``back``) through doors.

    Each room has its own 15-30 landmark IDs (random, disjoint); each frame sees every
    landmark of the current room with one probability drawn in [0.6, 0.9] for that frame. The
    last ``door_frames`` frames of a visit also see each landmark of the next room with
    probability ``door_share``, the first ``door_frames`` of the next visit the previous room's.
    """
    rng = np.random.default_rng(seed)
    sizes = rng.integers(15, 31, size=rooms)
    ids = rng.choice(2 * 10**6, size=int(sizes.sum()), replace=False) - 10**6
    marks = np.split(ids, np.cumsum(sizes)[:-1])
    route = list(range(rooms)) + (list(range(rooms - 2, -1, -1)) if back else [])
    frames: Frames = []
    doors: list[int] = []
    for visit, room in enumerate(route):
        if visit:
            doors.append(len(frames))
        length = int(rng.integers(stay[0], stay[1] + 1))
        for t in range(length):
            seen = marks[room][rng.random(marks[room].size) < rng.uniform(0.6, 0.9)].tolist()
            if visit + 1 < len(route) and t >= length - door_frames:
                other = marks[route[visit + 1]]
                seen += other[rng.random(other.size) < door_share].tolist()
            if visit > 0 and t < door_frames:
                other = marks[route[visit - 1]]
                seen += other[rng.random(other.size) < door_share].tolist()
            rng.shuffle(seen)
            frames.append([int(f) for f in seen])
    return Walk(
        frames=frames,
        rooms=tuple(frozenset(int(f) for f in m.tolist()) for m in marks),
        route=tuple(route),
        doors=tuple(doors),
    )


def observe_all(partitioner: Partitioner, frames: Frames, start: int = 0) -> list[Transition]:
    """Observe frames with seq = start + index (stamp = seq); return the transitions."""
    found: list[Transition] = []
    for offset, frame in enumerate(frames):
        seq = start + offset
        transition = partitioner.observe(seq, float(seq), frame)
        if transition is not None:
            found.append(transition)
    return found


def assert_same_state(a: PartitionerState, b: PartitionerState) -> None:
    """Field by field equality of two partitioner states (arrays compared exactly)."""
    for field in fields(a.graph):
        left, right = getattr(a.graph, field.name), getattr(b.graph, field.name)
        assert left.dtype == right.dtype, field.name
        assert np.array_equal(left, right), field.name
    assert len(a.history) == len(b.history)
    for x, y in zip(a.history, b.history, strict=True):
        assert x.seq == y.seq
        assert np.array_equal(x.features, y.features)
    for field in fields(a):
        if field.name not in {"graph", "history"}:
            assert getattr(a, field.name) == getattr(b, field.name), field.name


# -- snapshots as older versions wrote them ---------------------------------------------------


def as_npz_snapshot(
    data: bytes, module: ModuleType, edit: Callable[[dict[str, Any]], None]
) -> bytes:
    """A method's snapshot rewritten as its versions before the framing stored it.

    That is an ``.npz`` archive with a ``meta`` array; ``module`` is the method's snapshot
    module, and ``edit`` changes the meta in place first (its version, fields it lacked).
    """
    meta, arrays = unframe(data, module._MAGIC, module._ARRAYS)
    edit(meta)
    old = {"meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays}
    buffer = io.BytesIO()
    np.savez(buffer, **old)  # type: ignore[arg-type]
    return buffer.getvalue()

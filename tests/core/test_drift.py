"""The drift certificate: a carried λ2 floor is a proof, and decisions do not change."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from lessmap.core import CovGraph, Partitioner, PartitionParams
from lessmap.core.paper import drift
from lessmap.core.paper.counts import BlockChanges, Changes
from lessmap.core.paper.drift import Floor, carry, cross_norm
from lessmap.core.paper.snapshot import from_bytes, to_bytes
from lessmap.core.paper.spectral import fiedler_pair
from lessmap.files.frames import read_frames
from tests.conftest import dataset
from tests.core.helpers import random_connected, room_walk
from tests.core.test_certificate import decisions

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from tests.core.helpers import Frames


def changes_between(before: NDArray[np.float64], after: NDArray[np.float64]) -> Changes:
    """Brute force: the upper entries of ``after`` that differ from ``before`` (padded)."""
    m = before.shape[0]
    padded = np.zeros_like(after)
    padded[:m, :m] = before
    delta = np.triu(after - padded, k=1)
    rows, cols = np.nonzero(delta)
    return Changes(rows, cols, delta[rows, cols])


def blocks_between(
    before: NDArray[np.float64], after: NDArray[np.float64], extra: NDArray[np.int64]
) -> BlockChanges:
    """Brute force in the dense store's form: the old rows that moved, plus ``extra`` ones."""
    m = before.shape[0]
    delta = after[:m, :m] - before
    rows = np.union1d(np.flatnonzero((delta != 0.0).any(axis=1)), extra).astype(np.int64)
    return BlockChanges(m, rows, delta[rows], after[m:])


def perturbed(
    rng: np.random.Generator, w: NDArray[np.float64], share: float, scale: float, added: int
) -> NDArray[np.float64]:
    """W with a share of its entries rescaled, a few new edges and ``added`` new nodes."""
    n = w.shape[0]
    out = np.zeros((n + added, n + added))
    out[:n, :n] = np.triu(w, k=1)
    hit = np.triu(rng.random((n, n)) < share, k=1)
    out[:n, :n][hit] *= 1.0 + scale * rng.uniform(-1.0, 1.0, int(hit.sum()))
    for new in range(n, n + added):
        partners = rng.choice(new, size=min(new, 1 + int(rng.integers(0, 6))), replace=False)
        out[partners, new] = rng.uniform(0.05, 1.0, partners.size)
    out = np.clip(out, 0.0, 1.0)
    symmetric: NDArray[np.float64] = out + out.T
    return symmetric


@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(3, 40),
    share=st.floats(0.0, 1.0),
    scale=st.sampled_from([0.0, 1e-6, 0.01, 0.2, 1.0]),
    added=st.integers(0, 4),
)
@settings(max_examples=300, deadline=None)
def test_the_carried_floor_never_exceeds_lambda2(
    seed: int, n: int, share: float, scale: float, added: int
) -> None:
    rng = np.random.default_rng(seed)
    w0 = random_connected(rng, n, float(rng.uniform(0.1, 1.0))).toarray()
    lambda2_then, _ = fiedler_pair(w0)
    w1 = perturbed(rng, w0, share, scale, added)
    degrees = w1.sum(axis=1)
    floor = Floor(lambda2_then, w0.sum(axis=1))
    lower = carry(floor, degrees, changes_between(w0, w1))
    extra = rng.choice(n, size=int(rng.integers(0, n)), replace=False)
    from_blocks = carry(floor, degrees, blocks_between(w0, w1, extra))
    if degrees.min() > 0.0:
        lambda2_now, _ = fiedler_pair(w1)
        assert lower <= lambda2_now + 1e-12  # LAPACK's own error, not the margin
        assert from_blocks <= lambda2_now + 1e-12
        # The same sums; only the allowance differs (blocks count more terms).
        assert abs(from_blocks - lower) <= 1e-10 * (1.0 + abs(lower))
    else:
        assert lower == from_blocks == -np.inf


@pytest.mark.parametrize("seed", range(5))
def test_the_floor_is_tight_for_small_changes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    w0 = random_connected(rng, 30, 0.4).toarray()
    floor = Floor(0.5, w0.sum(axis=1))
    unmoved = carry(floor, w0.sum(axis=1), changes_between(w0, w0))
    assert 0.5 - 1e-12 < unmoved < 0.5  # nothing moved: only the rounding allowance
    for scale in (1e-3, 1e-6):
        w1 = perturbed(rng, w0, 0.3, scale, 0)
        moved = float(np.linalg.norm(w1 - w0))
        lower = carry(floor, w1.sum(axis=1), changes_between(w0, w1))
        assert 0.5 - 20 * moved <= lower <= 0.5


@pytest.mark.parametrize("seed", range(40))
def test_the_cross_norm_bounds_a_cancelling_block(seed: int) -> None:
    # Old nodes joined by tiny weights, every new node joined to every old one alike: then
    # S'_ON is nearly 2 u'_O u'_Nᵀ and the expansion of ||B||_F² cancels to its rounding.
    # Without the allowance, the expansion fell below the entrywise norm in most of these.
    rng = np.random.default_rng(seed)
    old, new = int(rng.integers(5, 60)), int(rng.integers(1, 60))
    n = old + new
    w = np.zeros((n, n))
    w[:old, old:] = float(rng.uniform(0.1, 1.0))
    w[old:, :old] = w[:old, old:].T
    w[:old, :old] = 10.0 ** rng.uniform(-14, -8)
    np.fill_diagonal(w, 0.0)
    degrees = w.sum(axis=1)
    u = np.sqrt(degrees / degrees.sum())
    s = w / np.sqrt(np.outer(degrees, degrees))
    entrywise = float(np.linalg.norm(2.0 * np.outer(u[:old], u[old:]) - s[:old, old:]))
    square_sum = float(np.sum(np.square(s[:old, old:])))
    rank_one = 4.0 * float(np.sum(np.square(u[:old]))) * float(np.sum(np.square(u[old:])))
    overlap = 4.0 * float(np.sum(s[:old, old:] * np.outer(u[:old], u[old:])))
    slack = drift._rounding(old * new + n)
    assert cross_norm(square_sum, rank_one, overlap, slack) >= entrywise


@pytest.mark.parametrize("dense_max_nodes", [400, 2])
def test_both_stores_report_the_changes_since_the_mark(dense_max_nodes: int) -> None:
    rng = np.random.default_rng(3)
    graph = CovGraph(dense_max_nodes)
    frames = [rng.choice(60, size=12, replace=False).tolist() for _ in range(40)]
    for seq, frame in enumerate(frames[:20]):
        graph.add_frame(seq, frame)
    before = graph.covrate_dense().copy()
    graph.mark()
    found = graph.changes()
    assert found is not None
    if isinstance(found, BlockChanges):
        assert not found.moved.any()
        found = found.entries()
    assert found.rows.size == 0
    for seq, frame in enumerate(frames[20:], start=20):
        graph.add_frame(seq, [*frame, 100 + seq])  # a new node in every frame
    after = graph.covrate_dense()
    found = graph.changes()
    expected = changes_between(before, after)
    assert found is not None
    assert isinstance(found, BlockChanges) == (dense_max_nodes == 400)
    if isinstance(found, BlockChanges):
        found = found.entries()
    got = sorted(zip(found.rows.tolist(), found.cols.tolist(), found.delta, strict=True))
    want = sorted(zip(expected.rows.tolist(), expected.cols.tolist(), expected.delta, strict=True))
    assert got == want
    assert len(want) > 100
    assert np.allclose(graph.degrees(), after.sum(axis=1), rtol=1e-14, atol=0.0)  # sum order


def laser() -> PartitionParams:
    return PartitionParams.from_profile("laser")


@pytest.fixture
def floor_on_small_graphs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Carry the floor from 2 nodes up, so that the data sets' small graphs exercise it."""
    monkeypatch.setattr(drift, "DRIFT_MIN_NODES", 2)


@pytest.mark.usefixtures("floor_on_small_graphs")
@pytest.mark.parametrize("name", ["dlr.frames.jsonl", "mrclam6.frames.jsonl"])
def test_decisions_with_the_floor_equal_full_solves_on_datasets(name: str) -> None:
    frames = [list(row.features) for row in read_frames(dataset(name))]
    fast = Partitioner(laser())
    full = Partitioner(laser(), always_solve=True)
    assert decisions(fast, frames) == decisions(full, frames)
    assert full.transitions > 10


@pytest.mark.usefixtures("floor_on_small_graphs")
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("dense_max_nodes", [400, 40])
def test_decisions_with_the_floor_equal_full_solves_on_room_walks(
    seed: int, dense_max_nodes: int
) -> None:
    walk = room_walk(seed, rooms=5, back=True, door_frames=2, door_share=0.2)
    params = PartitionParams(dense_max_nodes=dense_max_nodes)
    fast = Partitioner(params)
    full = Partitioner(params, always_solve=True)
    assert decisions(fast, walk.frames) == decisions(full, walk.frames)
    assert fast.transitions >= 1


def decisions_with_restores(frames: Frames, cuts: set[int]) -> list[tuple[object, ...]]:
    partitioner = Partitioner(laser())
    found: list[tuple[object, ...]] = []
    for seq, frame in enumerate(frames):
        if seq in cuts:
            partitioner = from_bytes(to_bytes(partitioner))  # the floor is dropped here
        transition = partitioner.observe(seq, float(seq), frame)
        evaluation = partitioner.last_evaluation
        assert evaluation is not None
        found.append((seq, evaluation.nodes, evaluation.transition, transition))
    return found


@pytest.mark.usefixtures("floor_on_small_graphs")
@pytest.mark.parametrize("seed", range(3))
def test_a_restore_mid_stream_gives_the_same_later_decisions(seed: int) -> None:
    walk = room_walk(seed, rooms=4, back=True, door_frames=2, door_share=0.2)
    rng = np.random.default_rng(seed)
    cuts = {int(c) for c in rng.choice(len(walk.frames), size=8, replace=False)}
    cuts |= {d + k for d in walk.doors[:2] for k in range(-2, 3)}
    assert decisions_with_restores(walk.frames, cuts) == decisions_with_restores(walk.frames, set())

"""The λ2 certificate: decisions settled by a Cholesky proof are the decisions of a full solve."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import sparse

from lessmap.core import Partitioner, PartitionParams
from lessmap.core.paper.spectral import (
    CERTIFICATE_MAX_NODES,
    Bisection,
    Components,
    fiedler_pair,
    frobenius_floor,
    lambda2_exceeds,
    split_graph,
)
from lessmap.files.frames import read_frames
from tests.conftest import dataset
from tests.core.helpers import random_connected, room_walk, two_cliques

if TYPE_CHECKING:
    from tests.core.helpers import Frames


def decisions(partitioner: Partitioner, frames: Frames) -> list[tuple[object, ...]]:
    """Every decision's outcome and, for transitions, everything they publish."""
    found: list[tuple[object, ...]] = []
    for seq, frame in enumerate(frames):
        transition = partitioner.observe(seq, float(seq), frame)
        evaluation = partitioner.last_evaluation
        assert evaluation is not None
        found.append((seq, evaluation.nodes, evaluation.components, evaluation.transition))
        if transition is not None:
            t = transition
            found.append((t.boundary_seq, t.reason, t.ncut, t.lambda2, t.closed, t.opened))
            found.append(t.boundary_features)
    return found


@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 60),
    density=st.floats(0.05, 1.0),
    bound=st.sampled_from([0.0, 0.1, 0.2, 0.5, 1.0]),
)
@settings(max_examples=300, deadline=None)
def test_the_certificate_is_sound_and_tight(
    seed: int, n: int, density: float, bound: float
) -> None:
    w = random_connected(np.random.default_rng(seed), n, density).toarray()
    lambda2, _ = fiedler_pair(w)
    proven = lambda2_exceeds(w, bound)
    if proven:
        assert lambda2 > bound
    if lambda2 > bound + 1e-6:
        assert proven, f"λ2 = {lambda2} > {bound} not proven"


@pytest.mark.parametrize("weak", [0.0, 1e-3, 0.05, 0.3])
def test_the_certificate_fails_near_a_split_and_on_a_disconnected_graph(weak: float) -> None:
    order = np.arange(20, dtype=np.int64)
    w = two_cliques(10, weak, order).toarray()
    lambda2, _ = fiedler_pair(w) if weak > 0 else (0.0, None)
    assert lambda2_exceeds(w, 0.2) is (lambda2 > 0.2)
    assert not lambda2_exceeds(w, lambda2 + 1e-6)


def test_an_isolated_node_is_never_certified_and_csr_agrees_with_dense() -> None:
    w = np.zeros((3, 3))
    w[0, 1] = w[1, 0] = 1.0
    assert not lambda2_exceeds(w, 0.0)
    assert not lambda2_exceeds(sparse.csr_array(w), 0.0)
    graph = random_connected(np.random.default_rng(0), 10, 1.0)
    lambda2, _ = fiedler_pair(graph.toarray())
    for bound in (0.0, lambda2 - 1e-6, lambda2 + 1e-6):
        assert lambda2_exceeds(graph, bound) is lambda2_exceeds(graph.toarray(), bound)


def test_the_certificate_refuses_graphs_beyond_its_rounding_argument() -> None:
    # A ring one node over the limit: λ2 = 1 - cos(2π/n) ≈ 7.9e-7 > 0 + margin, so its
    # Cholesky would pass, but the rounding bound no longer fits in the margin: no proof.
    n = CERTIFICATE_MAX_NODES + 1
    rows = np.arange(n)
    upper = sparse.csr_array((np.ones(n), (rows, (rows + 1) % n)), shape=(n, n))
    ring = sparse.csr_array(upper + upper.T)
    assert not lambda2_exceeds(ring, 0.0)


def test_split_graph_finds_components_without_searching_connected_graphs() -> None:
    order = np.arange(8, dtype=np.int64)
    apart = split_graph(two_cliques(4, 0.0, order).toarray())
    assert isinstance(apart, Components)
    assert apart.count == 2
    assert apart.labels.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    three = np.zeros((9, 9))
    for block in (slice(0, 3), slice(3, 6), slice(6, 9)):
        three[block, block] = 1.0
    np.fill_diagonal(three, 0.0)
    apart3 = split_graph(three)
    assert isinstance(apart3, Components)
    assert (apart3.count, apart3.labels.tolist()) == (3, [0, 0, 0, 1, 1, 1, 2, 2, 2])
    joined = split_graph(two_cliques(4, 0.01, order).toarray())
    assert isinstance(joined, Bisection)
    assert joined.labels.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("profile", ["laser", "monocular"])
def test_certified_decisions_equal_full_solves_on_room_walks(seed: int, profile: str) -> None:
    walk = room_walk(seed, rooms=5, back=True, door_frames=2, door_share=0.2)
    params = PartitionParams.from_profile(profile)
    fast = Partitioner(params)
    full = Partitioner(params, always_solve=True)
    assert decisions(fast, walk.frames) == decisions(full, walk.frames)
    assert fast.transitions >= 1


def test_certified_decisions_equal_full_solves_on_dlr() -> None:
    path = dataset("dlr.frames.jsonl")
    frames = [list(row.features) for row in read_frames(path)]
    fast = Partitioner(PartitionParams.from_profile("laser"))
    full = Partitioner(PartitionParams.from_profile("laser"), always_solve=True)
    assert decisions(fast, frames) == decisions(full, frames)
    assert full.transitions == 115


@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 80),
    density=st.floats(0.05, 1.0),
    scale=st.sampled_from([1e-90, 1e-3, 1.0, 1e6]),
)
@settings(max_examples=300, deadline=None)
def test_the_frobenius_floor_never_exceeds_lambda2(
    seed: int, n: int, density: float, scale: float
) -> None:
    graph = sparse.csr_array(random_connected(np.random.default_rng(seed), n, density) * scale)
    lambda2, _ = fiedler_pair(graph.toarray())
    assert frobenius_floor(graph.toarray()) <= lambda2
    assert frobenius_floor(graph) <= lambda2


@pytest.mark.parametrize("n", [3, 10, 40, 200])
def test_the_frobenius_floor_proves_a_complete_graph_and_nothing_apart(n: int) -> None:
    # K_n: λ2 = n / (n - 1) and ||S||_F² = n / (n - 1), so the floor is 1 - 1/√(n - 1)
    complete = np.ones((n, n)) - np.eye(n)
    expected = 1.0 - 1.0 / np.sqrt(n - 1)
    assert expected - 1e-9 < frobenius_floor(complete) <= expected
    assert expected - 1e-9 < frobenius_floor(sparse.csr_array(complete)) <= expected
    apart = two_cliques(n, 0.0, np.arange(2 * n, dtype=np.int64))
    assert frobenius_floor(apart.toarray()) <= 0.0
    assert frobenius_floor(apart) <= 0.0
    assert frobenius_floor(np.zeros((n, n))) == -np.inf  # no degrees: no bound


def test_decisions_the_frobenius_floor_settles_are_those_of_a_full_solve() -> None:
    # a room walk at the laser profile's bound: most decisions are proven by the floor alone
    walk = room_walk(3, rooms=5, back=True, door_frames=2, door_share=0.2)
    params = PartitionParams.from_profile("laser")
    fast = Partitioner(params)
    full = Partitioner(params, always_solve=True)
    proven = 0
    for seq, frame in enumerate(walk.frames):
        fast.observe(seq, float(seq), frame)
        w = fast.graph.similarity()
        proven += bool(w.shape[0] >= 2 and frobenius_floor(w) > params.lambda2_min)
    assert proven > len(walk.frames) // 2
    assert decisions(Partitioner(params), walk.frames) == decisions(full, walk.frames)
    assert fast.transitions >= 1

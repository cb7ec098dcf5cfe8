"""The dense small-graph form and the CSR form hold the same graph and make the same calls."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import sparse

from lessmap.core import CovGraph, Partitioner, PartitionParams
from lessmap.core.paper import covgraph
from lessmap.core.paper.counts import BlockChanges, Changes
from tests.core.helpers import observe_all, room_walk


def is_dense(graph: CovGraph) -> bool:
    return graph.is_dense  # a call, so the type checker does not pin the value across updates


def in_dense_store(graph: CovGraph) -> bool:
    return graph.dense_store  # a call, as above


frame_lists = st.lists(st.lists(st.integers(0, 25), max_size=8), min_size=1, max_size=40)


@settings(max_examples=200, deadline=None)
@given(frame_lists, st.integers(0, 30))
def test_dense_and_sparse_forms_hold_the_same_counts_and_w(
    frames: list[list[int]], dense_max: int
) -> None:
    dense, sparse_form = CovGraph(dense_max_nodes=dense_max), CovGraph(dense_max_nodes=0)
    for seq, frame in enumerate(frames):
        dense.add_frame(seq, frame)
        sparse_form.add_frame(seq, frame)
        if seq % 3 == 0:  # reads in between exercise the touched-rows refresh of both forms
            np.testing.assert_array_equal(
                dense.covrate().toarray(), sparse_form.covrate().toarray()
            )
    assert not sparse_form.is_dense
    assert dense.is_dense == (dense.node_count <= dense_max and dense_max > 0)
    np.testing.assert_array_equal(
        dense.edge_counts().toarray(), sparse_form.edge_counts().toarray()
    )
    assert dense.edge_count == sparse_form.edge_count
    np.testing.assert_array_equal(dense.covrate_dense(), sparse_form.covrate().toarray())
    a, b = dense.state(), sparse_form.state()
    for name in ("feature_ids", "counts", "edge_indptr", "edge_indices", "edge_counts"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_a_graph_that_outgrows_the_dense_limit_switches_and_keeps_its_counts() -> None:
    graph = CovGraph(dense_max_nodes=5)
    graph.add_frame(0, [1, 2, 3])
    assert graph.is_dense
    graph.add_frame(1, [3, 4, 5, 6, 7])  # node 6 would be the sixth: switch mid-frame
    assert not is_dense(graph)
    assert graph.pair_count(3, 7) == 1
    assert graph.pair_count(1, 2) == 1
    assert graph.count(3) == 2
    graph.keep_only(graph.nodes_of([1, 2, 3]))  # small again: back to the dense form
    assert is_dense(graph)
    assert graph.pair_count(1, 3) == 1
    assert graph.count(3) == 2


@pytest.mark.parametrize("seed", range(6))
def test_partitioner_decides_the_same_on_both_forms(seed: int) -> None:
    walk = room_walk(seed, rooms=4, back=True)
    dense = observe_all(Partitioner(PartitionParams()), walk.frames)
    sparse_only = observe_all(Partitioner(PartitionParams(dense_max_nodes=2)), walk.frames)
    assert [(t.seq, t.boundary_seq, t.reason) for t in dense] == [
        (t.seq, t.boundary_seq, t.reason) for t in sparse_only
    ]
    assert [(t.closed.features, t.opened.features, t.boundary_features) for t in dense] == [
        (t.closed.features, t.opened.features, t.boundary_features) for t in sparse_only
    ]
    for a, b in zip(dense, sparse_only, strict=True):
        assert a.ncut == pytest.approx(b.ncut, abs=1e-9)
        assert a.lambda2 == pytest.approx(b.lambda2, abs=1e-9)


# -- the dense store above dense_max_nodes (dense graphs): the sparse store's CSR ------------


def dense_frames(seed: int, *, pool: int = 40, seen: int = 24, frames: int = 70) -> list[list[int]]:
    """Frames of ``seen`` random landmarks of a room of ``pool``; the room changes at half
    time, with two frames that see both: most pairs of a room's landmarks become edges."""
    rng = np.random.default_rng(seed)
    rooms = rng.choice(10**6, size=2 * pool, replace=False).reshape(2, pool)
    out: list[list[int]] = []
    for t in range(frames):
        room = int(t >= frames // 2)
        picked = rng.choice(rooms[room], size=seen, replace=False).tolist()
        if frames // 2 - 1 <= t <= frames // 2:
            picked += rng.choice(rooms[1 - room], size=seen // 2, replace=False).tolist()
        out.append([int(f) for f in picked])
    return out


def same_csr(a: sparse.csr_array, b: sparse.csr_array) -> None:
    """The same CSR array for array: shapes, index dtypes and the bits of every entry."""
    assert a.shape == b.shape
    assert a.indptr.dtype == b.indptr.dtype
    assert a.indices.dtype == b.indices.dtype
    assert np.array_equal(a.indptr, b.indptr)
    assert np.array_equal(a.indices, b.indices)
    assert a.data.tobytes() == b.data.tobytes()


def as_entries(changes: Changes | BlockChanges | None) -> dict[tuple[int, int], float]:
    assert changes is not None
    listed = changes.entries() if isinstance(changes, BlockChanges) else changes
    rows, cols, delta = listed.rows.tolist(), listed.cols.tolist(), listed.delta.tolist()
    return {(i, j): d for i, j, d in zip(rows, cols, delta, strict=True)}


@pytest.mark.parametrize("seed", range(4))
def test_a_dense_graph_above_the_limit_keeps_the_dense_store_and_the_sparse_stores_csr(
    seed: int,
) -> None:
    dense_max = 12
    graph, reference = CovGraph(dense_max_nodes=dense_max), CovGraph(dense_max_nodes=0)
    above = 0
    for seq, frame in enumerate(dense_frames(seed)):
        if seq == 10:
            graph.mark()
            reference.mark()
        graph.add_frame(seq, frame)
        reference.add_frame(seq, frame)
        w = graph.similarity()
        assert graph.is_dense == (graph.node_count <= dense_max)
        if graph.node_count > dense_max:
            assert isinstance(w, sparse.csr_array)  # the solver's input is CSR, as before
            above += graph.dense_store
        same_csr(graph.covrate(), reference.covrate())
        if isinstance(w, sparse.csr_array):
            same_csr(w, reference.covrate())
        assert graph.edge_count == reference.edge_count
        np.testing.assert_allclose(graph.degrees(), reference.degrees(), rtol=1e-13)
        if seq >= 10:
            assert as_entries(graph.changes()) == as_entries(reference.changes())
    assert above > 30  # the dense store did hold the graph above the limit
    same_csr(graph.edge_counts(), reference.edge_counts())
    a, b = graph.state(), reference.state()
    for name in ("feature_ids", "counts", "first_seen", "edge_indptr", "edge_indices"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(a.edge_counts, b.edge_counts)


def share_percent(graph: CovGraph) -> float:
    n = graph.node_count
    return 200.0 * graph.edge_count / (n * (n - 1))


def test_the_dense_store_is_entered_and_left_with_hysteresis() -> None:
    graph = CovGraph(dense_max_nodes=4)
    graph.add_frame(0, list(range(20)))  # a clique: every pair an edge
    graph.covrate()
    assert graph.dense_store
    assert not graph.is_dense
    held, seq = True, 1
    history: list[tuple[bool, float]] = []
    feature = 1000
    # Thin the graph out with pairs of new features (one edge each), then fill it again
    # with cliques of known ones: the store follows the share with hysteresis.
    plan = [[feature + 2 * k, feature + 2 * k + 1] for k in range(40)]
    every = list(range(20)) + list(range(feature, feature + 80))
    plan += [every[k : k + 40] for k in range(0, 61, 4)] + [every]
    for frame in plan:
        graph.add_frame(seq, frame)
        seq += 1
        graph.covrate()  # W read: every pair is counted, the store may change here
        share = share_percent(graph)
        expected = share >= (covgraph.DENSE_STAY_PERCENT if held else covgraph.DENSE_ENTER_PERCENT)
        assert in_dense_store(graph) == expected, (share, held)
        held = in_dense_store(graph)
        history.append((held, share))
        # The store after a restore follows from the state alone (the entry share).
        restored = CovGraph.from_state(graph.state(), 4)
        assert restored.dense_store == (share >= covgraph.DENSE_ENTER_PERCENT)
        same_csr(restored.covrate(), graph.covrate())
    stay, enter = covgraph.DENSE_STAY_PERCENT, covgraph.DENSE_ENTER_PERCENT
    assert history[0][0]
    assert history[-1][0]
    assert any(dense and stay <= share < enter for dense, share in history)  # kept
    assert any(not dense for dense, _ in history)  # left
    assert any(not dense and stay <= share < enter for dense, share in history)  # not back yet


def test_the_dense_store_stops_at_its_node_cap(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(covgraph, "DENSE_STORE_MAX_NODES", 30)
    graph, reference = CovGraph(dense_max_nodes=4), CovGraph(dense_max_nodes=0)
    for seq, frame in enumerate([list(range(25)), list(range(20, 40)), list(range(30))]):
        graph.add_frame(seq, frame)
        reference.add_frame(seq, frame)
        assert in_dense_store(graph) == (graph.node_count <= 30)
        same_csr(graph.covrate(), reference.covrate())
    assert not in_dense_store(graph)  # 40 nodes: sparse, even at this density
    graph.keep_only(graph.nodes_of(range(25)))
    assert in_dense_store(graph)  # 25 nodes, a clique: dense again


def transitions_of(partitioner: Partitioner, frames: list[list[int]]) -> list[tuple[object, ...]]:
    """Every decision's outcome (as ``benchmarks.core_bench`` compares them)."""
    found: list[tuple[object, ...]] = []
    for seq, frame in enumerate(frames):
        transition = partitioner.observe(seq, float(seq), frame)
        evaluation = partitioner.last_evaluation
        assert evaluation is not None
        outcome: tuple[object, ...] = (evaluation.seq, evaluation.nodes, evaluation.transition)
        if transition is not None:
            t = transition
            outcome += (t.boundary_seq, t.reason, t.closed.features, t.opened.features)
            outcome += (t.boundary_features, t.ncut, t.lambda2)
        found.append(outcome)
    return found


@pytest.mark.parametrize("seed", range(4))
def test_decisions_with_the_dense_store_above_the_limit_equal_the_sparse_store_and_lapack(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    frames = dense_frames(seed, pool=60, seen=30, frames=90)
    params = PartitionParams(dense_max_nodes=20)  # ARPACK above 20 nodes
    with_dense_store = transitions_of(Partitioner(params), frames)
    exact = transitions_of(
        Partitioner(PartitionParams(dense_max_nodes=10**6), always_solve=True), frames
    )
    monkeypatch.setattr(covgraph, "DENSE_STORE_MAX_NODES", 0)  # the sparse store above 20
    sparse_store = transitions_of(Partitioner(params), frames)
    assert with_dense_store == sparse_store  # bit for bit: the same CSR, the same solves
    assert [d[:3] for d in with_dense_store] == [d[:3] for d in exact]
    moves = [d for d in with_dense_store if len(d) > 3]
    assert moves, "the stream crosses a door"
    for ours, reference in zip(moves, [d for d in exact if len(d) > 3], strict=True):
        assert ours[:8] == reference[:8]
        assert ours[8] == pytest.approx(reference[8], abs=1e-9)
        assert ours[9] == pytest.approx(reference[9], abs=1e-9)

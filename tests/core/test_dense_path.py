"""The dense small-graph form and the CSR form hold the same graph and make the same calls."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from lessmap.core import CovGraph, Partitioner, PartitionParams
from tests.core.helpers import observe_all, room_walk


def is_dense(graph: CovGraph) -> bool:
    return graph.is_dense  # a call, so the type checker does not pin the value across updates


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

"""CovGraph counts (n_i, a_ij) and CovRate W (Eq. 1) against brute-force recounts."""

from __future__ import annotations

import itertools
from dataclasses import fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from lessmap.core import CovGraph, CovGraphState, GraphError
from tests.core.helpers import brute_counts, brute_covrate

if TYPE_CHECKING:
    from scipy import sparse

# A small alphabet makes repeats, duplicates within a frame and shared pairs likely; the
# extremes check that IDs are kept as int64 values, not as indices.
ALPHABET = [0, 1, 2, 3, 4, 5, 6, 7, -3, 2**62, -(2**62)]
FRAME = st.lists(st.sampled_from(ALPHABET), max_size=8)
FRAMES = st.lists(FRAME, max_size=25)
EXAMPLES = settings(max_examples=150, deadline=None)


def build(frames: list[list[int]], first_seq: int = 0) -> CovGraph:
    graph = CovGraph()
    for seq, frame in enumerate(frames, start=first_seq):
        graph.add_frame(seq, frame)
    return graph


def assert_bitwise_equal(a: sparse.csr_array, b: sparse.csr_array) -> None:
    assert a.shape == b.shape
    assert a.dtype == b.dtype
    assert np.array_equal(a.indptr, b.indptr)
    assert np.array_equal(a.indices, b.indices)
    assert a.data.tobytes() == b.data.tobytes()


def assert_same_graph(a: CovGraph, b: CovGraph) -> None:
    left, right = a.state(), b.state()
    for field in fields(CovGraphState):
        x, y = getattr(left, field.name), getattr(right, field.name)
        assert x.dtype == y.dtype == np.int64, field.name
        assert np.array_equal(x, y), field.name
    assert_bitwise_equal(a.covrate(), b.covrate())


@given(frames=FRAMES)
@EXAMPLES
def test_counts_match_a_brute_force_recount(frames: list[list[int]]) -> None:
    graph = CovGraph()
    for seq, frame in enumerate(frames):
        nodes = graph.add_frame(seq, frame)
        assert nodes.tolist() == sorted(nodes.tolist())
        assert set(graph.feature_ids[nodes].tolist()) == set(frame)
    nodes_ref, pairs_ref = brute_counts(frames)

    assert graph.node_count == len(nodes_ref)
    assert graph.edge_count == len(pairs_ref)
    for feature in ALPHABET:
        assert graph.count(feature) == nodes_ref.get(feature, 0)
        assert graph.pair_count(feature, feature) == 0
    for a, b in itertools.permutations(ALPHABET, 2):
        assert graph.pair_count(a, b) == pairs_ref.get(frozenset((a, b)), 0)

    ids = graph.feature_ids.tolist()
    first_appearance = list(dict.fromkeys(f for frame in frames for f in frame))
    assert ids == first_appearance
    assert graph.counts.tolist() == [nodes_ref[f] for f in ids]
    first_seq = {f: seq for seq, frame in reversed(list(enumerate(frames))) for f in frame}
    assert graph.first_seen.tolist() == [first_seq[f] for f in ids]

    a_ij = graph.edge_counts()
    assert a_ij.dtype == np.int64
    expected = [[pairs_ref.get(frozenset((a, b)), 0) if a != b else 0 for b in ids] for a in ids]
    assert np.array_equal(a_ij.toarray(), np.array(expected, dtype=np.int64).reshape(a_ij.shape))


def test_duplicates_within_a_frame_count_once() -> None:
    graph = build([[5, 5, 5, 6], [6, 6], [5, 6, 5]])
    assert graph.count(5) == 2
    assert graph.count(6) == 3
    assert graph.pair_count(5, 6) == graph.pair_count(6, 5) == 2
    assert graph.node_count == 2
    assert graph.edge_count == 1


@given(frames=FRAMES, empties=st.lists(st.integers(0, 25), max_size=10))
@EXAMPLES
def test_empty_frames_change_nothing(frames: list[list[int]], empties: list[int]) -> None:
    plain, padded = CovGraph(), CovGraph()
    for index, frame in enumerate(frames):
        plain.add_frame(2 * index, frame)
        padded.add_frame(2 * index, frame)
        for _ in range(empties.count(index)):
            assert padded.add_frame(2 * index + 1, []).size == 0
    assert_same_graph(plain, padded)


@given(frames=FRAMES)
@EXAMPLES
def test_covrate_is_eq_1_symmetric_in_unit_range_with_zero_diagonal(
    frames: list[list[int]],
) -> None:
    graph = build(frames)
    w = graph.covrate()
    assert w.dtype == np.float64
    assert w.shape == (graph.node_count, graph.node_count)
    dense = w.toarray()
    assert np.array_equal(dense, dense.T)
    assert np.all(np.diag(dense) == 0.0)
    assert np.all((dense >= 0.0) & (dense <= 1.0))
    nodes_ref, pairs_ref = brute_counts(frames)
    # The same IEEE division of the same integers: equal to the last bit.
    assert np.array_equal(dense, brute_covrate(graph.feature_ids.tolist(), nodes_ref, pairs_ref))
    # Sparse: an entry is stored exactly where the pair was seen.
    assert w.nnz == 2 * len(pairs_ref)


READS = ["covrate", "edge_count", "edge_counts", "pair_count", "state"]


def read(graph: CovGraph, how: str) -> None:
    if how == "covrate":
        graph.covrate()
    elif how == "edge_count":
        assert graph.edge_count >= 0
    elif how == "edge_counts":
        graph.edge_counts()
    elif how == "pair_count":
        graph.pair_count(0, 1)
    else:
        graph.state()


@given(
    frames=FRAMES,
    reads=st.dictionaries(st.integers(0, 25), st.lists(st.sampled_from(READS), max_size=3)),
)
@EXAMPLES
def test_reading_between_frames_gives_the_same_w_as_reading_once(
    frames: list[list[int]], reads: dict[int, list[str]]
) -> None:
    # Every read merges the pending pairs and refreshes only the touched rows (_flush); the
    # result must not depend on when the reads happened.
    interleaved, once = CovGraph(), CovGraph()
    for seq, frame in enumerate(frames):
        interleaved.add_frame(seq, frame)
        once.add_frame(seq, frame)
        for how in reads.get(seq, []):
            read(interleaved, how)
    assert_same_graph(interleaved, once)


def test_refresh_after_counts_change_without_new_edges() -> None:
    # Frames whose pairs all exist already change n_i but not the CSR structure: the
    # incremental path must still update every entry with a touched endpoint.
    graph = build([[1, 2, 3], [1, 2]])
    graph.covrate()
    graph.add_frame(2, [1, 2])
    graph.add_frame(3, [3])
    w = graph.covrate().toarray()
    # n = (3, 3, 2); a_12 = 3, a_13 = a_23 = 1
    assert w[0, 1] == 1.0
    assert w[0, 2] == w[1, 2] == 0.5
    assert_bitwise_equal(graph.covrate(), build([[1, 2, 3], [1, 2], [1, 2], [3]]).covrate())


@given(frames=FRAMES, after=FRAMES, data=st.data())
@EXAMPLES
def test_keep_only_keeps_the_kept_nodes_counts_and_internal_edges(
    frames: list[list[int]], after: list[list[int]], data: st.DataObject
) -> None:
    graph = build(frames)
    ids = graph.feature_ids.tolist()
    chosen: list[int] = []
    if ids:
        chosen = data.draw(st.lists(st.sampled_from(range(len(ids))), unique=True), "kept")
    graph.keep_only(np.array(chosen, dtype=np.int64))  # any order, renumbered in old order

    kept = [ids[i] for i in sorted(chosen)]
    nodes_ref, pairs_ref = brute_counts(frames)
    assert graph.feature_ids.tolist() == kept
    assert graph.node_count == len(kept)
    for feature in ALPHABET:
        assert graph.count(feature) == (nodes_ref[feature] if feature in kept else 0)
    for a, b in itertools.combinations(ALPHABET, 2):
        inside = a in kept and b in kept
        assert graph.pair_count(a, b) == (pairs_ref.get(frozenset((a, b)), 0) if inside else 0)
    kept_nodes = {f: n for f, n in nodes_ref.items() if f in kept}
    kept_pairs = {p: c for p, c in pairs_ref.items() if p <= set(kept)}
    assert graph.edge_count == len(kept_pairs)
    assert np.array_equal(graph.covrate().toarray(), brute_covrate(kept, kept_nodes, kept_pairs))

    # Later frames count on top of the kept counts.
    for seq, frame in enumerate(after, start=len(frames)):
        graph.add_frame(seq, frame)
    more_nodes, more_pairs = brute_counts(after)
    total_nodes = {f: kept_nodes.get(f, 0) + more_nodes.get(f, 0) for f in {*kept, *more_nodes}}
    total_pairs = {
        p: kept_pairs.get(p, 0) + more_pairs.get(p, 0) for p in {*kept_pairs, *more_pairs}
    }
    assert np.array_equal(
        graph.covrate().toarray(),
        brute_covrate(graph.feature_ids.tolist(), total_nodes, total_pairs),
    )


@given(before=FRAMES, after=FRAMES, read_before=st.booleans())
@EXAMPLES
def test_state_round_trip_continues_exactly(
    before: list[list[int]], after: list[list[int]], read_before: bool
) -> None:
    original = build(before)
    if read_before:
        original.covrate()
    restored = CovGraph.from_state(original.state())
    assert_same_graph(original, restored)
    uninterrupted = build(before + after)
    for seq, frame in enumerate(after, start=len(before)):
        original.add_frame(seq, frame)
        restored.add_frame(seq, frame)
    assert_same_graph(restored, uninterrupted)
    assert_same_graph(original, uninterrupted)


def test_state_is_a_copy() -> None:
    graph = build([[1, 2], [2, 3]])
    state = graph.state()
    graph.add_frame(2, [1, 2, 3, 4])
    assert state.counts.tolist() == [1, 2, 1]
    assert CovGraph.from_state(state).count(4) == 0


def bad_states() -> list[Any]:
    good = build([[1, 2, 3], [3, 4]]).state()
    return [
        pytest.param(replace(good, counts=good.counts[:-1]), id="short counts"),
        pytest.param(replace(good, first_seen=good.first_seen[1:]), id="short first_seen"),
        pytest.param(replace(good, edge_indptr=good.edge_indptr[:-1]), id="short indptr"),
        pytest.param(
            replace(good, feature_ids=np.array([1, 2, 3, 1], dtype=np.int64)), id="repeated ids"
        ),
    ]


@pytest.mark.parametrize("state", bad_states())
def test_inconsistent_state_is_a_graph_error(state: CovGraphState) -> None:
    with pytest.raises(GraphError, match="inconsistent CovGraph state"):
        CovGraph.from_state(state)


def test_feature_id_views_are_read_only() -> None:
    graph = build([[1, 2]])
    for view in (graph.feature_ids, graph.counts, graph.first_seen):
        with pytest.raises(ValueError, match="read-only"):
            view[0] = 9


def test_memory_edges_charge_a_large_dense_store_its_bytes() -> None:
    from lessmap.core.paper.counts import SPARSE_BYTES_PER_EDGE, DenseCounts

    small = CovGraph(dense_max_nodes=400)
    small.add_frame(0, range(30))
    assert small.is_dense
    assert small.memory_edges == small.edge_count  # small graphs: edges, as always

    big = CovGraph(dense_max_nodes=20)
    big.add_frame(0, range(30))  # complete: every pair is an edge
    big.covrate()
    assert big.dense_store
    assert not big.is_dense
    store = big._store
    assert isinstance(store, DenseCounts)
    held = store.held_bytes()
    assert big.memory_edges == -(-held // SPARSE_BYTES_PER_EDGE)
    assert big.memory_edges > big.edge_count == 435

    sparse_only = CovGraph(dense_max_nodes=0)
    sparse_only.add_frame(0, range(30))
    assert not sparse_only.dense_store
    assert sparse_only.memory_edges == sparse_only.edge_count == 435

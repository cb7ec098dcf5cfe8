"""Both count stores behind the one CountStore interface, against brute force and each other."""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import sparse

from lessmap.core import CovGraph, Partitioner, PartitionParams
from lessmap.core.paper.counts import DenseCounts, SparseCounts, UpperCounts
from lessmap.core.paper.spectral import (
    components,
    cut_endpoints,
    fiedler_pair,
    normalized_cut,
    split_graph,
)
from tests.core.helpers import brute_counts, brute_covrate, random_connected, room_walk

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.core.paper.counts import CountStore

NODES = 12
STORES: list[Callable[[int, UpperCounts], CountStore]] = [
    lambda nodes, upper: DenseCounts(nodes, NODES, upper),
    lambda nodes, upper: SparseCounts(nodes, upper),
    # The dense store's row-by-row refresh, which it uses above FULL_REFRESH_MAX_NODES.
    lambda nodes, upper: DenseCounts(nodes, NODES, upper, full_refresh_max_nodes=0),
]
STORE_IDS = ["dense", "sparse", "dense-rows"]
FRAMES = st.lists(st.lists(st.integers(0, NODES - 1), max_size=7), max_size=30)
EXAMPLES = settings(max_examples=100, deadline=None)


class Driver:
    """Feeds frames of node indices to a store the way CovGraph does (n_i, touched, resize)."""

    def __init__(self, make: Callable[[int, UpperCounts], CountStore]) -> None:
        self.store = make(0, UpperCounts.empty())
        self.ids: list[int] = []  # feature of each node, in order of first appearance
        self.counts = np.zeros(NODES, dtype=np.int64)
        self.touched = np.zeros(NODES, dtype=bool)

    @property
    def nodes(self) -> int:
        return len(self.ids)

    def add(self, frame: list[int]) -> None:
        for feature in frame:
            if feature not in self.ids:
                self.ids.append(feature)
                self.store.resize(self.nodes)
        nodes = np.array(sorted({self.ids.index(f) for f in frame}), dtype=np.int64)
        if nodes.size == 0:
            return
        self.counts[nodes] += 1
        self.touched[nodes] = True
        self.store.add_frame(nodes)

    def refresh(self) -> None:
        self.store.refresh(self.counts[: self.nodes], self.touched[: self.nodes])
        self.touched[:] = False


def assert_same_upper(a: UpperCounts, b: UpperCounts) -> None:
    for x, y in zip((a.indptr, a.indices, a.counts), (b.indptr, b.indices, b.counts), strict=True):
        assert x.dtype == y.dtype == np.int64
        assert np.array_equal(x, y)


@pytest.mark.parametrize("make", STORES, ids=STORE_IDS)
@given(frames=FRAMES, reads=st.sets(st.integers(0, 29)))
@EXAMPLES
def test_store_counts_and_w_match_brute_force(
    make: Callable[[int, UpperCounts], CountStore], frames: list[list[int]], reads: set[int]
) -> None:
    driver = Driver(make)
    for k, frame in enumerate(frames):
        driver.add(frame)
        if k in reads:  # reading in between must not change what is read at the end
            driver.refresh()
    driver.refresh()
    n, ids, store = driver.nodes, driver.ids, driver.store
    counts, pairs = brute_counts(frames)
    w = brute_covrate(ids, counts, pairs)
    assert store.similarity_array().tobytes() == w.tobytes()
    assert np.array_equal(store.similarity_csr().toarray(), w)
    assert store.edge_count() == len(pairs)
    a = np.zeros((n, n), dtype=np.int64)
    for i, j in itertools.combinations(range(n), 2):
        a[i, j] = pairs.get(frozenset((ids[i], ids[j])), 0)
        assert store.pair_count(i, j) == store.pair_count(j, i) == a[i, j]
    upper = store.upper()
    assert upper.nodes == n
    assert all(x.dtype == np.int64 for x in (upper.indptr, upper.indices, upper.counts))
    assert np.array_equal(upper.csr().toarray(), a)


@pytest.mark.parametrize("dense_make", [STORES[0], STORES[2]], ids=["dense", "dense-rows"])
@given(frames=FRAMES, kept=st.sets(st.integers(0, NODES - 1)), after=FRAMES)
@EXAMPLES
def test_both_stores_agree_bit_for_bit_through_reload_and_subgraph(
    dense_make: Callable[[int, UpperCounts], CountStore],
    frames: list[list[int]],
    kept: set[int],
    after: list[list[int]],
) -> None:
    dense, sparse_store = Driver(dense_make), Driver(STORES[1])
    for frame in frames:
        dense.add(frame)
        sparse_store.add(frame)
    dense.refresh()
    sparse_store.refresh()
    assert dense.store.similarity_array().tobytes() == (
        sparse_store.store.similarity_array().tobytes()
    )
    assert_same_upper(dense.store.upper(), sparse_store.store.upper())
    chosen = np.array(sorted(k for k in kept if k < dense.nodes), dtype=np.int64)
    assert_same_upper(dense.store.upper(chosen), sparse_store.store.upper(chosen))
    # Each store rebuilt from the other's arrays counts on exactly like the original.
    swapped = [
        dense_make(dense.nodes, sparse_store.store.upper()),
        STORES[1](dense.nodes, dense.store.upper()),
    ]
    for store, original in zip(swapped, (dense, sparse_store), strict=True):
        driver = Driver(dense_make)
        driver.store, driver.ids = store, list(original.ids)
        driver.counts[:] = original.counts
        for frame in after:
            driver.add(frame)
            original.add(frame)
        driver.refresh()
        original.refresh()
        assert driver.store.similarity_array().tobytes() == (
            original.store.similarity_array().tobytes()
        )
        assert driver.store.edge_count() == original.store.edge_count()


def test_dense_store_grows_by_doubling_up_to_its_limit() -> None:
    store = DenseCounts(0, 100, UpperCounts.empty())
    for n in range(1, 101):
        store.resize(n)
        store.add_frame(np.arange(n, dtype=np.int64)[-2:] if n >= 2 else np.zeros(1, np.int64))
    store.refresh(np.full(100, 2, dtype=np.int64), np.ones(100, dtype=bool))
    assert store.similarity_array().shape == (100, 100)
    assert store.edge_count() == 99  # the chain 0-1-2-...-99
    assert store.pair_count(98, 99) == 1


@pytest.mark.parametrize("dense_max", [1, 5, 17, 40])
@pytest.mark.parametrize("seed", range(3))
def test_a_graph_crossing_the_dense_limit_has_the_w_of_the_sparse_store_from_the_start(
    dense_max: int, seed: int
) -> None:
    walk = room_walk(seed, rooms=3, back=True)
    crossing, always_sparse = CovGraph(dense_max_nodes=dense_max), CovGraph(dense_max_nodes=0)
    forms: set[bool] = set()
    for seq, frame in enumerate(walk.frames):
        forms.add(crossing.is_dense)  # dense while empty: a limit of 1 crosses in frame 0
        crossing.add_frame(seq, frame)
        always_sparse.add_frame(seq, frame)
        forms.add(crossing.is_dense)
        w, reference_w = crossing.covrate(), always_sparse.covrate()
        assert w.toarray().tobytes() == reference_w.toarray().tobytes()
        native = crossing.similarity()
        assert isinstance(native, np.ndarray) == crossing.is_dense
        assert isinstance(always_sparse.similarity(), sparse.csr_array)
    assert forms == {True, False}  # the walk did cross the limit
    a, b = crossing.state(), always_sparse.state()
    for name in ("feature_ids", "counts", "first_seen", "edge_indptr", "edge_indices"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(a.edge_counts, b.edge_counts)


@pytest.mark.parametrize("seed", range(4))
def test_spectral_entry_points_agree_on_both_forms_of_w(seed: int) -> None:
    rng = np.random.default_rng(seed)
    w = random_connected(rng, 30, density=0.15)
    dense = w.toarray()
    labels = (rng.random(30) < 0.4).astype(np.int8)
    labels[0], labels[1] = 0, 1
    side = labels != 0
    assert normalized_cut(dense, labels) == pytest.approx(normalized_cut(w, labels), rel=1e-12)
    count_dense, comp_dense = components(dense)
    count_sparse, comp_sparse = components(w)
    assert count_dense == count_sparse == 1
    assert np.array_equal(comp_dense, comp_sparse)
    ends_dense = np.unique(cut_endpoints(dense, side))
    ends_sparse = np.unique(cut_endpoints(w, side))
    assert np.array_equal(ends_dense, ends_sparse)
    lambda2_dense, _ = fiedler_pair(dense)
    lambda2_sparse, _ = fiedler_pair(w, dense_max_nodes=2)  # the ARPACK path
    assert lambda2_dense == pytest.approx(lambda2_sparse, abs=1e-9)
    split_dense, split_sparse = split_graph(dense), split_graph(w)
    assert split_dense.labels.tolist() == split_sparse.labels.tolist()


@pytest.mark.parametrize(
    "params",
    [
        PartitionParams(),
        PartitionParams(min_cluster_size=6),
        PartitionParams(dense_max_nodes=2),
        PartitionParams(ncut_min=0.0, lambda2_min=0.0),
    ],
    ids=["default", "guarded", "sparse", "never-spectral"],
)
def test_evaluation_and_transition_come_from_the_same_decision(params: PartitionParams) -> None:
    walk = room_walk(1, rooms=4, back=True)
    for always_solve in (False, True):
        partitioner = Partitioner(params, always_solve=always_solve)
        for seq, frame in enumerate(walk.frames):
            transition = partitioner.observe(seq, float(seq), frame)
            evaluation = partitioner.last_evaluation
            if evaluation is None or evaluation.seq != seq:
                continue  # no test at this frame (empty frame), the last evaluation stands
            assert evaluation.transition == (transition is not None)
            if transition is not None:
                assert transition.seq == seq
                assert (evaluation.ncut, evaluation.lambda2) == (
                    transition.ncut,
                    transition.lambda2,
                )
                assert (transition.ncut is None) == (evaluation.components > 1)
            if evaluation.lambda2_above is not None:
                assert not always_solve
                assert evaluation.ncut is None
                assert evaluation.lambda2 is None


@given(frames=FRAMES, reads=st.sets(st.integers(0, 29)))
@EXAMPLES
def test_the_dense_stores_csr_is_the_sparse_stores_array_for_array(
    frames: list[list[int]], reads: set[int]
) -> None:
    dense, sparse_store = Driver(STORES[0]), Driver(STORES[1])
    for k, frame in enumerate(frames):
        dense.add(frame)
        sparse_store.add(frame)
        if k in reads:
            dense.refresh()
            sparse_store.refresh()
            a, b = dense.store.similarity_csr(), sparse_store.store.similarity_csr()
            assert a.indptr.dtype == b.indptr.dtype
            assert a.indices.dtype == b.indices.dtype
            assert np.array_equal(a.indptr, b.indptr)
            assert np.array_equal(a.indices, b.indices)
            assert a.data.tobytes() == b.data.tobytes()


def test_a_dense_store_grows_by_an_eighth_past_its_doubling_limit() -> None:
    store = DenseCounts(0, 100, UpperCounts.empty(), doubling_max=20)
    sides = []
    for n in range(1, 101):
        store.resize(n)
        sides.append(store.similarity_array().base.shape[0])  # type: ignore[union-attr]
        if n >= 2:
            store.add_frame(np.array([n - 2, n - 1], dtype=np.int64))
    assert sorted(set(sides)) == [
        16,
        20,
        22,
        24,
        27,
        30,
        33,
        37,
        41,
        46,
        51,
        57,
        64,
        72,
        81,
        91,
        100,
    ]
    store.refresh(np.full(100, 2, dtype=np.int64), np.ones(100, dtype=bool))
    assert store.edge_count() == 99
    assert store.pair_count(0, 1) == store.pair_count(98, 99) == 1
    csr = store.similarity_csr()
    assert csr.nnz == 198
    assert np.all(csr.data == 0.5)

"""Shi–Malik bisection (§3.2) against dense generalized eigensolvers and brute force."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import linalg, sparse

from lessmap.core import GraphError, normalized_bisection, normalized_cut
from lessmap.core.paper.spectral import components, fiedler_pair, two_means_1d
from tests.core.helpers import (
    as_partition,
    brute_ncut,
    planted_two_blocks,
    random_connected,
    two_cliques,
)


def reference_pair(w: sparse.csr_array) -> tuple[float, float, np.ndarray]:
    """λ2, λ3 and v2 of L v = λ D v from LAPACK's dense generalized solver."""
    dense = w.toarray()
    d = np.diag(dense.sum(axis=1))
    top = min(2, dense.shape[0] - 1)
    values, vectors = linalg.eigh(d - dense, d, subset_by_index=[0, top])
    return float(values[1]), float(values[2]) if values.size > 2 else np.inf, vectors[:, 1]


def reference_two_means(values: np.ndarray) -> tuple[frozenset[frozenset[int]], float]:
    """Best threshold split of 1-D points by explicit SSE, and the margin to the runner-up."""
    order = np.argsort(values, kind="stable").tolist()
    scored: list[tuple[float, frozenset[frozenset[int]]]] = []
    for k in range(1, len(order)):
        left, right = values[order[:k]], values[order[k:]]
        sse = float(((left - left.mean()) ** 2).sum() + ((right - right.mean()) ** 2).sum())
        scored.append((sse, frozenset({frozenset(order[:k]), frozenset(order[k:])})))
    scored.sort(key=lambda item: item[0])
    margin = scored[1][0] - scored[0][0] if len(scored) > 1 else np.inf
    return scored[0][1], margin / max(scored[0][0], 1e-300)


def check_against_reference(w: sparse.csr_array, dense_max_nodes: int) -> None:
    lambda2_ref, lambda3_ref, v2_ref = reference_pair(w)
    lambda2, v2 = fiedler_pair(w, dense_max_nodes=dense_max_nodes)
    assert lambda2 == pytest.approx(lambda2_ref, abs=1e-8)
    # v2 is a generalized eigenvector: L v2 = λ2 D v2, D-orthogonal to the constant v1.
    dense = w.toarray()
    degrees = dense.sum(axis=1)
    residual = (np.diag(degrees) - dense) @ v2 - lambda2 * degrees * v2
    assert np.linalg.norm(residual) <= 1e-6 * np.linalg.norm(degrees * v2)
    assert abs(degrees @ v2) <= 1e-6 * np.linalg.norm(degrees) * np.linalg.norm(v2)

    split = normalized_bisection(w, dense_max_nodes=dense_max_nodes)
    assert split.lambda2 == lambda2
    assert split.labels[0] == 0
    assert set(split.labels.tolist()) == {0, 1}
    # The split is only determined when v2 is (simple λ2) and 2-means has a clear winner.
    if lambda3_ref - lambda2_ref > 1e-4:
        expected, margin = reference_two_means(v2_ref)
        if margin > 1e-6:
            assert as_partition(split.labels) == expected


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("solver", ["dense", "arpack"])
def test_fiedler_pair_matches_lapack_on_random_graphs(seed: int, solver: str) -> None:
    rng = np.random.default_rng(seed)
    checked = 0
    for n in (3, 4, 5, 7, 12, 25, 60):
        w = random_connected(rng, n, density=float(rng.uniform(0.05, 0.3)))
        if solver == "arpack" and reference_pair(w)[0] >= 1.0 - 1e-6:
            continue  # λ2 >= 1 on the ARPACK path: test_lambda2_above_one_on_both_paths
        check_against_reference(w, dense_max_nodes=400 if solver == "dense" else 2)
        checked += 1
    assert checked >= 4


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("solver", ["dense", "arpack"])
def test_planted_blocks_split_into_the_blocks(seed: int, solver: str) -> None:
    rng = np.random.default_rng(100 + seed)
    for n in (8, 20, 60):
        w, planted = planted_two_blocks(rng, n, degree=min(6, n // 2 - 1), bridges=2)
        check_against_reference(w, dense_max_nodes=400 if solver == "dense" else 2)
        split = normalized_bisection(w, dense_max_nodes=400 if solver == "dense" else 2)
        assert as_partition(split.labels) == as_partition(planted)


@pytest.mark.parametrize("n", [450, 600])
def test_large_planted_blocks_on_the_arpack_path(n: int) -> None:
    rng = np.random.default_rng(n)
    w, planted = planted_two_blocks(rng, n, degree=10, bridges=5)
    check_against_reference(w, dense_max_nodes=400)  # n > 400: the default ARPACK path
    split = normalized_bisection(w)
    assert as_partition(split.labels) == as_partition(planted)
    assert split.lambda2 <= split.ncut
    assert split.ncut == pytest.approx(normalized_cut(w, planted), abs=1e-12)


def test_large_random_graph_on_the_arpack_path() -> None:
    rng = np.random.default_rng(7)
    check_against_reference(random_connected(rng, 500, density=0.01), dense_max_nodes=400)


@pytest.mark.parametrize(
    ("n", "dense_max_nodes"),
    [(3, 400), (10, 400), (3, 2), (10, 2), (450, 400)],
    ids=["dense-3", "dense-10", "arpack-3", "arpack-10", "default-450"],
)
def test_lambda2_above_one_on_both_paths(n: int, dense_max_nodes: int) -> None:
    # The complete graph K_n has λ2 = n / (n - 1) > 1 (every cut is bad). The ARPACK path
    # deflates v1 to the eigenvalue 0 of S = D^-1/2 W D^-1/2, which is then above 1 - λ2 < 0.
    w = sparse.csr_array(np.ones((n, n)) - np.eye(n))
    lambda2, v2 = fiedler_pair(w, dense_max_nodes=dense_max_nodes)
    assert lambda2 == pytest.approx(n / (n - 1), abs=1e-8)
    assert np.ptp(v2) > 1e-3 * np.abs(v2).max()  # not the constant v1


def brute_two_means(values: list[float]) -> float:
    """Least within-cluster sum of squares over every split into two non-empty sets."""
    points = np.array(values, dtype=np.float64)
    n = points.size
    masks = np.arange(1, 2 ** (n - 1))  # point n-1 always on side 0: each split once
    side = (masks[:, None] >> np.arange(n)[None, :] & 1).astype(bool)
    total = np.zeros(masks.size, dtype=np.float64)
    for members in (side, ~side):
        count = members.sum(axis=1)
        mean = (members * points).sum(axis=1) / count
        total += (members * (points[None, :] - mean[:, None]) ** 2).sum(axis=1)
    return float(total.min())


POINTS = st.lists(
    st.one_of(
        st.integers(-4, 4).map(float),  # repeated values
        st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False),
    ),
    min_size=2,
    max_size=10,
).filter(lambda v: len(set(v)) >= 2)


@given(values=POINTS)
@settings(max_examples=300, deadline=None)
def test_two_means_1d_is_the_brute_force_optimum(values: list[float]) -> None:
    points = np.array(values, dtype=np.float64)
    labels = two_means_1d(points)
    assert labels.dtype == np.int8
    assert labels[0] == 0
    assert set(labels.tolist()) == {0, 1}
    sse = sum(
        float(((points[labels == k] - points[labels == k].mean()) ** 2).sum()) for k in (0, 1)
    )
    best = brute_two_means(values)
    assert sse <= best + 1e-9 * max(1.0, best)
    for a, b in itertools.combinations(range(points.size), 2):
        if points[a] == points[b]:
            assert labels[a] == labels[b]


def test_two_means_1d_known_split() -> None:
    labels = two_means_1d(np.array([0.0, 10.0, 0.1, 9.9, 0.2, 10.0]))
    assert labels.tolist() == [0, 1, 0, 1, 0, 1]


@pytest.mark.parametrize("values", [[1.0], [2.0, 2.0, 2.0]])
def test_two_means_1d_needs_two_distinct_points(values: list[float]) -> None:
    with pytest.raises(GraphError, match="2-means needs"):
        two_means_1d(np.array(values))


GRAPH = st.tuples(st.integers(0, 2**32 - 1), st.integers(3, 12), st.floats(0.0, 0.8))


@given(graph=GRAPH, data=st.data())
@settings(max_examples=100, deadline=None)
def test_lambda2_is_a_lower_bound_of_ncut(
    graph: tuple[int, int, float], data: st.DataObject
) -> None:
    seed, n, density = graph
    w = random_connected(np.random.default_rng(seed), n, density)
    split = normalized_bisection(w)
    assert split.lambda2 >= 0.0
    assert split.lambda2 <= split.ncut + 1e-9
    other = data.draw(
        st.lists(st.booleans(), min_size=n, max_size=n).filter(lambda s: 0 < sum(s) < n)
    )
    assert split.lambda2 <= normalized_cut(w, np.array(other, dtype=np.int8)) + 1e-9
    if n <= 10:  # against the true minimum Ncut over every split
        dense = w.toarray()
        least = min(
            brute_ncut(dense, [bool(mask >> i & 1) for i in range(n)])
            for mask in range(1, 2 ** (n - 1))
        )
        assert split.lambda2 <= least + 1e-9
        assert split.ncut >= least - 1e-12


@given(graph=GRAPH, data=st.data())
@settings(max_examples=100, deadline=None)
def test_normalized_cut_matches_brute_force(
    graph: tuple[int, int, float], data: st.DataObject
) -> None:
    seed, n, density = graph
    w = random_connected(np.random.default_rng(seed), n, density)
    side = data.draw(
        st.lists(st.booleans(), min_size=n, max_size=n).filter(lambda s: 0 < sum(s) < n)
    )
    labels = np.array(side, dtype=np.int8)
    ncut = normalized_cut(w, labels)
    assert ncut == pytest.approx(brute_ncut(w.toarray(), side), rel=1e-12)
    assert normalized_cut(w, 1 - labels) == pytest.approx(ncut, rel=1e-12)  # sides symmetric


def test_normalized_cut_needs_two_sides() -> None:
    w = two_cliques(3, 0.5, np.arange(6))
    with pytest.raises(GraphError, match="two sides"):
        normalized_cut(w, np.zeros(6, dtype=np.int8))


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("solver", ["dense", "arpack"])
def test_two_cliques_joined_by_a_weak_edge(seed: int, solver: str) -> None:
    order = np.random.default_rng(seed).permutation(12)
    weak = 0.1
    w = two_cliques(6, weak, order)
    split = normalized_bisection(w, dense_max_nodes=400 if solver == "dense" else 2)
    first = frozenset(np.flatnonzero(order < 6).tolist())
    second = frozenset(np.flatnonzero(order >= 6).tolist())
    assert as_partition(split.labels) == {first, second}
    # cut = ε; each side: 6 nodes of degree 5, one of them + ε: assoc = 30 + ε.
    assert split.ncut == pytest.approx(2 * weak / (30 + weak), rel=1e-12)
    assert 0.0 < split.lambda2 <= split.ncut
    assert split.lambda2 == pytest.approx(reference_pair(w)[0], abs=1e-10)


@pytest.mark.parametrize(
    "w",
    [
        sparse.csr_array(np.zeros((1, 1))),
        sparse.csr_array(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])),
    ],
    ids=["one node", "isolated node"],
)
def test_fiedler_pair_rejects_degenerate_graphs(w: sparse.csr_array) -> None:
    with pytest.raises(GraphError):
        fiedler_pair(w)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 40), parts=st.integers(1, 6))
@settings(max_examples=200, deadline=None)
def test_both_forms_number_components_by_their_lowest_node(seed: int, n: int, parts: int) -> None:
    rng = np.random.default_rng(seed)
    part = rng.integers(0, parts, size=n)
    upper = np.triu((rng.random((n, n)) < 0.5) & (part[:, None] == part[None, :]), k=1)
    w = (upper | upper.T).astype(np.float64)
    count, labels = components(sparse.csr_array(w))
    dense_count, dense_labels = components(w)
    assert (count, labels.tolist()) == (dense_count, dense_labels.tolist())
    _, first = np.unique(labels, return_index=True)
    assert np.all(np.diff(first) > 0)  # component k starts after component k - 1
    assert np.array_equal(labels[first], np.arange(count))


@pytest.mark.parametrize("seed", range(10))
def test_sparse_ncut_equals_the_brute_force_sum(seed: int) -> None:
    rng = np.random.default_rng(seed)
    w = random_connected(rng, 30, 0.3)
    labels = (rng.random(30) < 0.5).astype(np.int8)
    labels[:2] = [1, 0]
    side = [bool(label) for label in labels.tolist()]
    assert normalized_cut(w, labels) == pytest.approx(brute_ncut(w.toarray(), side), rel=1e-12)

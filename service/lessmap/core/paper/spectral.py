"""Shi–Malik normalized spectral bisection of a CovGraph (LESS-mapping §3.2, Eqs. 2-3).

The generalized problem L v = λ D v (L = D - W) is solved through its symmetric form
L_sym = I - D^-1/2 W D^-1/2 = I - S: L_sym u = λ u with v = D^-1/2 u, the same eigenvalues.
Small graphs use LAPACK (exact, deterministic); large ones use ARPACK on S with the known
first eigenvector u1 = D^1/2 1 reflected out, so Lanczos converges on u2 alone instead of
fighting the eigenvalue cluster at 1 that a nearly separable graph produces.

Every entry point picks the dense or the sparse path of W once, at its top; the paths
(``_dense_*``, ``_sparse_*``) share only the formulas, never a branch on the form. Not MRPT's
variant (unnormalized Laplacian, an Ncut about twice Shi–Malik's): the paper's thresholds
are calibrated for the normalized problem.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, TypeAlias

import numpy as np
from scipy import linalg, sparse
from scipy.linalg import lapack
from scipy.sparse import csgraph
from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigsh

from lessmap.core.errors import GraphError

if TYPE_CHECKING:
    from numpy.typing import NDArray

#: Graphs up to this many nodes are solved densely (LAPACK); larger ones with ARPACK.
DENSE_MAX_NODES = 400

#: W as the CovGraph hands it over: CSR in general, a dense array for small graphs.
Similarity: TypeAlias = "sparse.csr_array | NDArray[np.float64]"

#: λ2 above this proves a dense graph connected without a search (see ``split_graph``).
CONNECTED_LAMBDA2 = 1e-9

#: ``lambda2_exceeds`` certifies λ2 > bound + this, above Cholesky's rounding (see there).
CERTIFICATE_MARGIN = 1e-8

#: ``lambda2_exceeds`` answers "not proven" above this size: its rounding bound, 1.5·n(n+1)·ε,
#: reaches ``CERTIFICATE_MARGIN`` at about 5,470 nodes (8.3e-9 at 5,000).
CERTIFICATE_MAX_NODES = 5000


@dataclass(frozen=True, slots=True)
class Bisection:
    """A two-way split of a connected graph and its spectral figures."""

    labels: NDArray[np.int8]  # (n,) 0 or 1; node 0 always has label 0
    ncut: float  # Shi–Malik Ncut of this split
    lambda2: float  # second smallest eigenvalue of L v = λ D v
    fiedler: NDArray[np.float64]  # (n,) v2, the generalized eigenvector (sign arbitrary)


@dataclass(frozen=True, slots=True)
class Components:
    """A graph that falls apart: how many components, and each node's component."""

    count: int  # > 1
    labels: NDArray[np.int32]  # (n,) numbered in order of their lowest node


# -- entry points: each picks the dense or the sparse path once, here ---------------------


def lambda2_exceeds(w: Similarity, bound: float) -> bool:
    """Return True when λ2 of L v = λ D v provably exceeds ``bound`` (dense W only).

    Most decisions are nowhere near a transition (λ2 around 0.9 in a room being walked), and
    proving λ2 > λ2_min settles one: by ``frobenius_floor`` when it suffices, else by a
    Cholesky factorization of a matrix that is positive definite exactly when λ2 > bound +
    ``CERTIFICATE_MARGIN`` (Sylvester's law of inertia), both cheaper than the eigen-solve.
    The margin covers the factorization's rounding up to ``CERTIFICATE_MAX_NODES``; larger
    graphs are never factorized. False means "not proven": the caller solves as usual, so
    decisions never change. The proofs: ``docs/design/drift-certificate.md``.

    Args:
        w: CovRate similarity, symmetric, non-negative, zero diagonal, shape (n, n).
        bound: the λ2 to beat (λ2_min, or a floor to establish above it).

    Returns:
        True when λ2 > bound is proven; False otherwise.
    """
    if w.shape[0] > CERTIFICATE_MAX_NODES or bound < 0.0:
        return False  # outside the rounding argument above: not proven, never wrong
    if isinstance(w, np.ndarray):
        return _dense_lambda2_exceeds(w, bound)
    return _sparse_lambda2_exceeds(w, bound)


def frobenius_floor(w: Similarity) -> float:
    """A proven lower bound of λ2 from ||S||_F alone (S = D^-1/2 W D^-1/2); -inf for none.

    S's eigenvalues are 1 - λk, the first exactly 1, so (1 - λ2)² <= ||S||_F² - 1 and
    λ2 >= 1 - √(||S||_F² - 1). A room's graph, nearly complete, has ||S||_F² close to 1,
    so the bound proves most decisions for a third of a Cholesky factorization's cost, and
    without its dense matrix. ``lambda2_exceeds`` tries it first.
    """
    if w.shape[0] < 2:
        return -np.inf
    if isinstance(w, np.ndarray):
        return _dense_frobenius_floor(w, _add_reduce(w, axis=1))
    return _sparse_frobenius_floor(w, _sparse_degrees(w))


def _floor_of(square_sum: float, rounding_terms: int) -> float:
    """The bound from a computed ||S||_F², raised first by (rounding_terms + 16)·ε of it.

    Callers count their rounding: 1/d_i is within n·ε, so a term w_ij² / (d_i d_j) within
    (2n + 3)·ε, and a sum of K non-negative terms within K·ε of their total (Higham §3.1),
    so the bound is a proof in floating point too; 16·ε and 4·ε cover the last roundings.
    Degrees under ``_TINY_DEGREE`` give none (callers): w_ij² could underflow there.
    """
    allowance = (rounding_terms + 16) * _EPS * square_sum
    return 1.0 - float(np.sqrt(max(square_sum + allowance - 1.0, 0.0))) - 4 * _EPS


_EPS = float(np.finfo(np.float64).eps)
_TINY_DEGREE = 1e-100  # above it, a w_ij² that underflows is negligible beside ||S||_F² >= 1


def split_graph(w: Similarity, *, dense_max_nodes: int = DENSE_MAX_NODES) -> Bisection | Components:
    """Return the components of W when it falls apart, else its normalized bisection.

    Small (dense) graphs are solved first and searched only when needed: a graph of k
    components has the eigenvalue 0 k times, which LAPACK's dsyevr returns within a few
    ulps of 0 (|λ| ≲ 1e-15 on this spectrum in [0, 2]), so λ2 > ``CONNECTED_LAMBDA2``
    proves one component. That skips the breadth-first search, which cost as much as the
    2-means under fleet load, in every decision but the rare ones near disconnection.
    Sparse graphs keep the search first: ARPACK is not asked to converge on a repeated 0.

    Args:
        w: CovRate similarity, symmetric, non-negative, zero diagonal, shape (n, n), n >= 2.
        dense_max_nodes: solve with LAPACK up to this size, ARPACK above.
    """
    if isinstance(w, np.ndarray):
        return _dense_split(w)
    return _sparse_split(w, dense_max_nodes)


def components(w: Similarity) -> tuple[int, NDArray[np.int32]]:
    """Return the number of connected components of W and each node's component label.

    Labels number the components in order of their lowest node, for both forms of W.
    """
    if isinstance(w, np.ndarray):
        return _dense_components(w > 0)
    return _sparse_components(w)


def normalized_cut(
    w: Similarity, labels: NDArray[np.integer], degrees: NDArray[np.float64] | None = None
) -> float:
    """Return Ncut(A, B) = cut/assoc(A, V) + cut/assoc(B, V) (Shi–Malik, PAPER.md Eq. 3).

    Args:
        w: symmetric similarity, shape (n, n).
        labels: (n,) 0/1 membership; both sides must be non-empty with positive degree.
        degrees: the row sums of W when the caller has them already.
    """
    side = np.asarray(labels) != 0
    if isinstance(w, np.ndarray):
        return _dense_ncut(w, side, w.sum(axis=1) if degrees is None else degrees)
    return _sparse_ncut(w, side, _sparse_degrees(w) if degrees is None else degrees)


def fiedler_pair(
    w: Similarity,
    *,
    dense_max_nodes: int = DENSE_MAX_NODES,
    degrees: NDArray[np.float64] | None = None,
) -> tuple[float, NDArray[np.float64]]:
    """Return λ2 and v2 of L v = λ D v for a connected similarity graph.

    Args:
        w: CovRate similarity, symmetric, non-negative, zero diagonal, shape (n, n), n >= 2,
            connected (check components first: D is singular on an isolated node).
        dense_max_nodes: solve a CSR W with LAPACK up to this size, ARPACK above (a dense
            W is always solved with LAPACK).
        degrees: the row sums of W when the caller has them already.

    Returns:
        λ2 (clipped at 0 against round-off) and the generalized eigenvector v2, shape (n,).
    """
    if isinstance(w, np.ndarray):
        return _dense_fiedler(w, w.sum(axis=1) if degrees is None else degrees)
    return _sparse_fiedler(w, _sparse_degrees(w) if degrees is None else degrees, dense_max_nodes)


def normalized_bisection(w: Similarity, *, dense_max_nodes: int = DENSE_MAX_NODES) -> Bisection:
    """Split a connected CovGraph in two by Shi–Malik normalized cut.

    Solves L v = λ D v (L = D - W) for the two smallest eigenpairs; v1 is constant on a
    connected graph, so 2-means on the rows of [v1 v2] is 2-means on the Fiedler vector v2.

    Args:
        w: CovRate similarity, symmetric, non-negative, zero diagonal, shape (n, n), n >= 2,
            connected; a CSR matrix or, for small graphs, a dense array.
        dense_max_nodes: solve with LAPACK up to this size, ARPACK above.

    Returns:
        Labels (n,), the Ncut of that split, λ2 and v2.

    References:
        Shi, Malik. "Normalized cuts and image segmentation." TPAMI 22 (2000).
        Vázquez-Martín et al. "LESS-mapping." RAS 60 (2012), Eqs. 2-4.
    """
    if isinstance(w, np.ndarray):
        return _dense_bisection(w, w.sum(axis=1))
    return _sparse_bisection(w, _sparse_degrees(w), dense_max_nodes)


def cut_endpoints(w: Similarity, side: NDArray[np.bool_]) -> NDArray[np.integer]:
    """Return the nodes at either end of every edge of W between ``side`` and the rest.

    Nodes repeat (how often depends on the form of W) and come in no particular order:
    callers want the set.
    """
    if isinstance(w, np.ndarray):
        return _dense_cut_endpoints(w, side)
    return _sparse_cut_endpoints(w, side)


# -- shared by both paths: the formulas ----------------------------------------------------


def two_means_1d(values: NDArray[np.float64]) -> NDArray[np.int8]:
    """Split 1-D points into the 2-means optimum (exact, deterministic).

    In one dimension the optimal 2-means clusters are separated by a threshold between two
    consecutive sorted values, so scanning the n - 1 thresholds with prefix sums finds the
    global optimum that Lloyd's iterations only approach. Equal values stay together.

    Returns:
        (n,) labels 0/1 with labels[0] == 0.
    """
    n = values.size
    if n < 2:
        msg = f"2-means needs at least 2 points, got {n}"
        raise GraphError(msg)
    centred = values - values.mean()  # centring keeps the prefix sums well conditioned
    ordered = np.sort(centred)
    prefix = np.cumsum(ordered)[:-1]  # sum of the k smallest, k = 1 .. n-1
    total = prefix[-1] + ordered[-1]
    k = np.arange(1, n, dtype=np.float64)
    # SSE = Σx² - S_left²/k - S_right²/(n-k); Σx² is constant, so maximize the rest.
    score = prefix**2 / k + (total - prefix) ** 2 / (n - k)
    score[ordered[1:] <= ordered[:-1]] = -np.inf  # no threshold between equal values
    split = int(np.argmax(score)) + 1
    if not np.isfinite(score[split - 1]):
        msg = "2-means needs at least two distinct values"
        raise GraphError(msg)
    # The split lies between two distinct sorted values, so a threshold on the centred
    # values gives the same clusters as labelling positions in the sorted order.
    labels: NDArray[np.int8] = (centred >= ordered[split]).astype(np.int8)
    if labels[0] != 0:
        labels ^= 1
    return labels


def _require_solvable(n: int, degrees: NDArray[np.float64]) -> None:
    if n < 2:
        msg = f"a bisection needs at least 2 nodes, got {n}"
        raise GraphError(msg)
    if not (degrees > 0).all():
        msg = f"node {int(np.argmin(degrees))} has no edge: split the components first"
        raise GraphError(msg)


def _ncut(cut: float, side: NDArray[np.bool_], degrees: NDArray[np.float64]) -> float:
    assoc_b = float(degrees[side].sum())
    assoc_a = float(degrees[~side].sum())
    if assoc_a <= 0.0 or assoc_b <= 0.0:
        msg = f"Ncut needs two sides of positive degree, got assoc {assoc_a} and {assoc_b}"
        raise GraphError(msg)
    return cut / assoc_a + cut / assoc_b


# -- dense path: small graphs, W a dense array, LAPACK ---------------------------------------


_add_reduce, _min_reduce = np.add.reduce, np.minimum.reduce


def _dense_lambda2_exceeds(w: NDArray[np.float64], bound: float) -> bool:
    n = w.shape[0]
    if n < 2:
        return False
    # The ufuncs' reductions that ``sum`` and ``min`` call, without their Python wrappers
    # (this runs at every decision): the same sums in the same order.
    degrees = _add_reduce(w, axis=1)
    if not _min_reduce(degrees) > 0.0:
        return False
    shift = bound + CERTIFICATE_MARGIN
    if _dense_frobenius_floor(w, degrees) > shift:
        return True  # proven by two matrix-vector products: most decisions stop here
    matrix = np.multiply.outer(degrees * ((shift + 1.0) / _add_reduce(degrees)), degrees)
    matrix -= w
    # The diagonal through a flat view: cheaper than ``ndarray.flat`` at tens of nodes.
    matrix.reshape(-1)[:: n + 1] += (1.0 - shift) * degrees
    _, info = lapack.dpotrf(matrix, lower=1, clean=0, overwrite_a=1)
    return bool(info == 0)


def _dense_frobenius_floor(w: NDArray[np.float64], degrees: NDArray[np.float64]) -> float:
    if not _min_reduce(degrees) > _TINY_DEGREE:
        return -np.inf
    inverse = 1.0 / degrees
    n = w.shape[0]
    return _floor_of(float(inverse @ (w * w) @ inverse), 4 * n)


def _dense_split(w: NDArray[np.float64]) -> Bisection | Components:
    # Solve first, search only when λ2 does not prove the graph connected (see split_graph).
    degrees = _add_reduce(w, axis=1)
    bisection: Bisection | None = None
    if _min_reduce(degrees) > 0.0:
        try:
            bisection = _dense_bisection(w, degrees)
        except GraphError:
            bisection = None  # a degenerate split of a graph that fell apart: search
        else:
            if bisection.lambda2 > CONNECTED_LAMBDA2:
                return bisection
    count, labels = _dense_components(w > 0)
    if count > 1:
        return Components(count=count, labels=labels)
    if bisection is not None:
        return bisection
    return _dense_bisection(w, degrees)  # raises the reason this graph cannot be split


def _dense_bisection(w: NDArray[np.float64], degrees: NDArray[np.float64]) -> Bisection:
    lambda2, fiedler = _dense_fiedler(w, degrees)
    labels = two_means_1d(fiedler)
    return Bisection(
        labels=labels, ncut=_dense_ncut(w, labels != 0, degrees), lambda2=lambda2, fiedler=fiedler
    )


def _dense_fiedler(
    w: NDArray[np.float64], degrees: NDArray[np.float64]
) -> tuple[float, NDArray[np.float64]]:
    n = w.shape[0]
    _require_solvable(n, degrees)
    inv_sqrt = 1.0 / np.sqrt(degrees)
    # No sparse containers to build: they cost more than the solve itself at tens of nodes.
    lsym = inv_sqrt[:, None] * w
    lsym *= inv_sqrt[None, :]
    np.negative(lsym, out=lsym)
    lsym.flat[:: n + 1] = 1.0  # I - D^-1/2 W D^-1/2, W's diagonal being 0
    lambda2, u2 = _lapack_second_pair(lsym)
    return max(lambda2, 0.0), u2 * inv_sqrt


def _dense_ncut(
    w: NDArray[np.float64], side: NDArray[np.bool_], degrees: NDArray[np.float64]
) -> float:
    return _ncut(float(w[~side][:, side].sum()), side, degrees)  # np.ix_'s block, half the cost


def _dense_components(adjacent: NDArray[np.bool_]) -> tuple[int, NDArray[np.int32]]:
    # Breadth-first search one level at a time on the boolean matrix. scipy's
    # connected_components validates a dense input through masked arrays, which took more
    # than the whole rest of a decision on room-sized graphs.
    n = adjacent.shape[0]
    labels = np.full(n, -1, dtype=np.int32)
    count = 0
    for start in range(n):
        if labels[start] >= 0:
            continue
        reached = np.zeros(n, dtype=bool)
        reached[start] = True
        frontier = reached.copy()
        while True:
            frontier = adjacent[frontier].any(axis=0) & ~reached
            if not frontier.any():
                break
            reached |= frontier
        labels[reached] = count
        count += 1
    return count, labels


def _dense_cut_endpoints(w: NDArray[np.float64], side: NDArray[np.bool_]) -> NDArray[np.integer]:
    rows, cols = np.nonzero(w[np.ix_(side, ~side)])
    ends: NDArray[np.integer] = np.concatenate(
        [np.flatnonzero(side)[rows], np.flatnonzero(~side)[cols]]
    )
    return ends


# -- sparse path: W a CSR matrix; LAPACK up to dense_max_nodes, ARPACK above ----------------


def _sparse_degrees(w: sparse.csr_array) -> NDArray[np.float64]:
    degrees: NDArray[np.float64] = np.asarray(w.sum(axis=1), dtype=np.float64).ravel()
    return degrees


def _sparse_frobenius_floor(w: sparse.csr_array, degrees: NDArray[np.float64]) -> float:
    if not degrees.min() > _TINY_DEGREE:
        return -np.inf
    inverse = 1.0 / degrees
    rows = np.repeat(inverse, np.diff(w.indptr))
    terms = w.data * w.data * rows * inverse[w.indices]
    # the terms' own rounding (3n), then one sum of all of them
    return _floor_of(float(terms.sum()), 3 * w.shape[0] + terms.size)


def _sparse_split(w: sparse.csr_array, dense_max_nodes: int) -> Bisection | Components:
    # Search first: ARPACK is not asked to converge on a repeated eigenvalue 0.
    count, labels = _sparse_components(w)
    if count > 1:
        return Components(count=count, labels=labels)
    return _sparse_bisection(w, _sparse_degrees(w), dense_max_nodes)


def _sparse_lambda2_exceeds(w: sparse.csr_array, bound: float) -> bool:
    # The dense certificate's matrix, written straight from the CSR entries (no dense W).
    n = w.shape[0]
    if n < 2:
        return False
    degrees = _sparse_degrees(w)
    if not degrees.min() > 0.0:
        return False
    shift = bound + CERTIFICATE_MARGIN
    if _sparse_frobenius_floor(w, degrees) > shift:
        return True  # no n x n matrix: most decisions stop here
    matrix = np.multiply.outer(degrees * ((shift + 1.0) / degrees.sum()), degrees)
    rows = np.repeat(np.arange(n), np.diff(w.indptr))
    matrix[rows, w.indices] -= w.data  # canonical CSR: no repeated entries
    matrix.flat[:: n + 1] += (1.0 - shift) * degrees
    # The transpose is Fortran-ordered, so LAPACK factorizes it in place (no copy); dpotrf
    # reads one triangle, and either triangle holds the same matrix up to rounding.
    _, info = lapack.dpotrf(matrix.T, lower=1, clean=0, overwrite_a=1)
    return bool(info == 0)


def _sparse_components(w: sparse.csr_array) -> tuple[int, NDArray[np.int32]]:
    # W is symmetric, so its strong components are its components; scipy's undirected
    # search builds the transpose first, a large share of a decision on big graphs.
    count, labels = csgraph.connected_components(w, directed=True, connection="strong")
    if count == 1:
        return 1, np.zeros(w.shape[0], dtype=np.int32)
    # Number the components in order of their lowest node, as the dense search does.
    _, lowest = np.unique(labels, return_index=True)
    order = np.empty(count, dtype=np.int32)
    order[np.argsort(lowest)] = np.arange(count, dtype=np.int32)
    return int(count), order[labels]


def _sparse_bisection(
    w: sparse.csr_array, degrees: NDArray[np.float64], dense_max_nodes: int
) -> Bisection:
    lambda2, fiedler = _sparse_fiedler(w, degrees, dense_max_nodes)
    labels = two_means_1d(fiedler)
    return Bisection(
        labels=labels, ncut=_sparse_ncut(w, labels != 0, degrees), lambda2=lambda2, fiedler=fiedler
    )


def _sparse_fiedler(
    w: sparse.csr_array, degrees: NDArray[np.float64], dense_max_nodes: int
) -> tuple[float, NDArray[np.float64]]:
    n = w.shape[0]
    _require_solvable(n, degrees)
    inv_sqrt = 1.0 / np.sqrt(degrees)
    # D^-1/2 W D^-1/2 on W's own index arrays: half the cost of two diagonal products.
    row_scale = np.repeat(inv_sqrt, np.diff(w.indptr))
    data = row_scale * w.data
    data *= inv_sqrt[w.indices]
    scaled = sparse.csr_array((data, w.indices, w.indptr), shape=w.shape)
    if n <= dense_max_nodes:
        lambda2, u2 = _lapack_second_pair(np.eye(n) - scaled.toarray())
    else:
        try:
            lambda2, u2 = _arpack_second_pair(scaled, np.sqrt(degrees))
        except ArpackNoConvergence:
            lambda2, u2 = _lapack_second_pair(np.eye(n) - scaled.toarray())
    return max(lambda2, 0.0), u2 * inv_sqrt


def _sparse_ncut(
    w: sparse.csr_array, side: NDArray[np.bool_], degrees: NDArray[np.float64]
) -> float:
    # cut = Σ_{i in B, j in A} W_ij: one product with W, no COO copy of its entries.
    cut = float((w @ (~side).astype(np.float64))[side].sum())
    return _ncut(cut, side, degrees)


def _sparse_cut_endpoints(w: sparse.csr_array, side: NDArray[np.bool_]) -> NDArray[np.integer]:
    coo = w.tocoo()
    crossing = side[coo.row] != side[coo.col]
    ends: NDArray[np.integer] = np.concatenate([coo.row[crossing], coo.col[crossing]])
    return ends


def _arpack_second_pair(
    scaled: sparse.csr_array, sqrt_degrees: NDArray[np.float64]
) -> tuple[float, NDArray[np.float64]]:
    n = scaled.shape[0]
    u1 = sqrt_degrees / np.linalg.norm(sqrt_degrees)

    def deflated(x: NDArray[np.float64]) -> NDArray[np.float64]:
        # S - 2 u1 u1ᵀ moves S's top eigenvalue from 1 to -1, the bottom of S's spectrum
        # [-1, 1], so the largest eigenvalue left is 1 - λ2 even when λ2 > 1.
        x = np.asarray(x, dtype=np.float64).ravel()
        y: NDArray[np.float64] = scaled @ x - 2.0 * u1 * (u1 @ x)
        return y

    operator = LinearOperator((n, n), matvec=deflated, dtype=np.float64)
    start = np.random.default_rng(n).standard_normal(n)  # seeded: same graph, same answer
    start -= u1 * (u1 @ start)
    values, vectors = eigsh(operator, k=1, which="LA", v0=start, tol=1e-12, maxiter=50 * n)
    return 1.0 - float(values[0]), np.asarray(vectors[:, 0], dtype=np.float64)


# -- eigen-solvers --------------------------------------------------------------------------


def _lapack_second_pair(lsym: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """The second smallest eigenpair of a symmetric matrix (overwritten), by LAPACK dsyevr.

    The same routine and arguments as ``scipy.linalg.eigh(lsym, subset_by_index=[0, 1])``,
    called directly: on room-sized graphs eigh's argument checks and workspace query cost
    about a third of the solve, at every decision.
    """
    lwork, liwork = _dsyevr_workspace(lsym.shape[0])
    values, vectors, found, _, info = lapack.dsyevr(
        lsym, compute_v=1, range="I", il=1, iu=2, lower=1,
        lwork=lwork, liwork=liwork, overwrite_a=1,
    )  # fmt: skip
    if info != 0 or found != 2:
        # Let scipy report what went wrong (it raises LinAlgError with the reason).
        values, vectors = linalg.eigh(lsym, subset_by_index=[0, 1])
    return float(values[1]), np.asarray(vectors[:, 1], dtype=np.float64)


@lru_cache(maxsize=512)
def _dsyevr_workspace(n: int) -> tuple[int, int]:
    """Return the optimal dsyevr workspace for order n (a LAPACK query; depends on n only)."""
    work, iwork, info = lapack.dsyevr_lwork(n, lower=1)
    if info != 0:
        msg = f"LAPACK dsyevr workspace query failed for order {n} (info {info})"
        raise GraphError(msg)
    return int(work), int(iwork)

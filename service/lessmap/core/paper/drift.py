"""A proven lower bound of λ2 carried from one decision to the next (the drift certificate).

Once λ2 is proven above a floor l, the next graph's λ2 is at least l minus how far the
frame can have moved the spectrum: O(changed entries + nodes) instead of a factorization or
an eigen-solve. The bound and its proof: ``docs/design/drift-certificate.md``. Rules:

1. The floor never decides anything the exact solver would not: it only proves
   λ2 > λ2_min + ``CERTIFICATE_MARGIN``; below, the partitioner proves afresh or solves.
2. Every norm is bounded by a Frobenius norm and the rounding allowance is subtracted
   explicitly (``_rounding``), so the bound is a proof in floating point too.
3. The floor is a cache of proofs, not session state: dropping it only costs a proof.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core.paper.counts import BlockChanges
from lessmap.core.paper.spectral import CERTIFICATE_MARGIN, lambda2_exceeds

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from lessmap.core.paper.counts import Changes
    from lessmap.core.paper.covgraph import CovGraph
    from lessmap.core.paper.spectral import Similarity

#: Graphs up to this many nodes may be proven by a dense Cholesky factorization when the
#: floor is lost (O(n²) memory, ~n³/3 flops); above, the sparse path solves every decision
#: the floor does not settle, so a huge session never allocates an n x n matrix.
PROOF_MAX_NODES = 4096

#: A fresh proof aims at bound + this share of (estimated λ2 - bound): the higher it is,
#: the longer the floor lasts; a miss costs one more factorization and lowers the estimate.
REACH = 0.75

#: Smaller graphs are proven by the plain Cholesky certificate at every decision: at tens of
#: nodes it costs less than the bookkeeping of carrying a floor.
DRIFT_MIN_NODES = 128

#: Fresh proofs aimed above the bound per decision before one at the bound itself.
AIMS = 2

#: A fresh proof aims above the bound only when the estimate exceeds it by this much.
MIN_HEADROOM = 0.02

#: After a floor that did not outlast one decision, the next sparse solves skip the
#: floor-setting Cholesky: 1, 2, 4, ... up to this many, until a floor lasts again. A
#: stream that brings hundreds of landmarks a frame (stereo, visual odometry) moves the
#: spectrum more per frame than any floor can absorb; there the factorization (≈ n³/3
#: flops, several solves' worth) would be paid at every decision and used by none.
MAX_SKIPPED_PROOFS = 16


@dataclass(frozen=True, slots=True)
class Floor:
    """λ2 of the graph at the mark is proven >= ``lower``; ``degrees`` are its d (n,)."""

    lower: float
    degrees: NDArray[np.float64]


def carry(floor: Floor, degrees: NDArray[np.float64], changes: Changes | BlockChanges) -> float:
    """Return a proven lower bound of λ2 now, from the floor at the mark (see the module).

    Args:
        floor: the proven floor and the degrees at the mark, shape (m,).
        degrees: the row sums of W now, shape (n,), n >= m.
        changes: what of W moved since the mark: its entries (sparse store) or its rows
            (dense store); both give the same sums up to rounding.

    Returns:
        The bound; -inf when it cannot be carried (an isolated node, fewer nodes).
    """
    old, n = floor.degrees.size, degrees.size
    if n < old or old < 2 or not degrees.min() > 0.0:
        return -np.inf
    total = float(degrees.sum())
    if isinstance(changes, BlockChanges):
        if changes.old != old:
            return -np.inf  # not the floor's mark: nothing to carry from
        sums = _block_sums(changes, degrees, total)
    else:
        sums = _entry_sums(changes, degrees, old, total)
    slack = _rounding(sums.terms + n)
    ratio = np.sqrt(floor.degrees / degrees[:old])
    rescaled = float(np.max(np.abs(ratio - 1.0))) * (1.0 + float(ratio.max()))
    u_now = np.sqrt(degrees / total)
    u_then = np.sqrt(floor.degrees / floor.degrees.sum())
    u_old = u_now[:old]
    norm_old = float(np.linalg.norm(u_old))
    turned = 2.0 * float(np.linalg.norm(u_old - u_then)) * (norm_old + 1.0)
    drift = float(np.sqrt(sums.old)) + rescaled + turned
    a = floor.lower - drift - slack * (abs(floor.lower) + drift + 1.0)
    if n == old:
        return a
    within = float(np.sqrt(sums.new))
    c = 1.0 - within - slack * (within + 1.0)
    beta = cross_norm(
        sums.cross,
        4.0 * norm_old**2 * float(np.sum(np.square(u_now[old:]))),
        4.0 * sums.overlap,
        slack,
    )
    lowest = 0.5 * (a + c) - float(np.hypot(0.5 * (a - c), beta))
    return lowest - slack * (abs(a) + abs(c) + beta)


@dataclass(frozen=True, slots=True)
class _Sums:
    """The sums ``carry`` needs, with s_ij = (W'_ij - W0_ij) / √(d'_i d'_j), u = √(d'/Σd')."""

    old: float  # Σ s² over the old x old block, both triangles: ||S'_OO - R S0 R||_F²
    new: float  # Σ s² over the new x new block, both triangles: ||S'_NN||_F²
    cross: float  # Σ s² over the new x old block, each pair once: ||S'_ON||_F²
    overlap: float  # Σ s_ij u_i u_j over the same block (= Σ W'_ij / Σd')
    terms: int  # products summed, for the rounding allowance


def _entry_sums(changes: Changes, degrees: NDArray[np.float64], old: int, total: float) -> _Sums:
    """The sums from the changed entries (i < j), each pair listed once."""
    inv_sqrt = 1.0 / np.sqrt(degrees)
    rows, cols = changes.rows, changes.cols
    scaled = changes.delta * inv_sqrt[rows] * inv_sqrt[cols]
    touches_new = cols >= old  # cols > rows: a new endpoint is always cols
    both_new = rows >= old
    cross = touches_new & ~both_new
    u_now = np.sqrt(degrees / total)
    return _Sums(
        old=2.0 * float(np.sum(np.square(scaled[~touches_new]))),
        new=2.0 * float(np.sum(np.square(scaled[both_new]))),
        cross=float(np.sum(np.square(scaled[cross]))),
        overlap=float(np.sum(scaled[cross] * u_now[rows[cross]] * u_now[cols[cross]])),
        terms=int(rows.size),
    )


def _block_sums(changes: BlockChanges, degrees: NDArray[np.float64], total: float) -> _Sums:
    """The same sums from the dense store's row blocks, by matrix-vector products.

    Old block: a changed pair (i, j) of old nodes has i or j among the moved rows R (only
    those were recomputed). The rows of R hold each pair with one end outside R once and
    each pair inside R twice (both rows), so the symmetric sum is
    Σ_{i in R} (1/d_i) Σ_j Δ_ij² w_j with w_j = 2/d_j outside R and 1/d_j inside: every
    term is non-negative, so nothing cancels. Entries that did not move are 0 in the block.
    New rows hold W' itself (0 at the mark); s_ij u_i u_j = W'_ij / Σd' exactly in exact
    arithmetic. Each term carries a handful of roundings (the difference, the square, the
    reciprocals and products) on top of the sums' own g_K, K <= the block sizes + n: inside
    ``_rounding``'s (K + 16)ε, as for the entry sums.
    """
    old, rows, moved, new = changes.old, changes.rows, changes.moved, changes.new
    inverse = 1.0 / degrees
    weights = 2.0 * inverse[:old]
    weights[rows] = inverse[rows]
    old_sum = float(inverse[rows] @ (np.square(moved) @ weights)) if rows.size else 0.0
    new_sum = cross_sum = overlap = 0.0
    if new.shape[0]:
        fresh = inverse[old:]
        new_sum = float(fresh @ (np.square(new[:, old:]) @ fresh))
        to_old = new[:, :old]
        cross_sum = float(fresh @ (np.square(to_old) @ inverse[:old]))
        overlap = float(to_old.sum()) / total
    return _Sums(old_sum, new_sum, cross_sum, overlap, int(moved.size + new.size))


def cross_norm(square_sum: float, rank_one: float, overlap: float, slack: float) -> float:
    """Return an upper bound of ||B||_F, B = 2 u'_O u'_Nᵀ - S'_ON, from its expansion.

    ||B||_F² = ||S'_ON||_F² + 4 ||u'_O||² ||u'_N||² - 4 Σ S'_ij u'_i u'_j: three sums that
    nearly cancel when the new nodes join the old ones like a complete bipartite graph, so
    the rounding of the sums (``slack`` relative to their magnitudes) is added before the
    square root. Dropping it would return 0 where ||B||_F is ~1e-7.
    """
    rounding = slack * (square_sum + rank_one + abs(overlap))
    return float(np.sqrt(max(0.0, square_sum + rank_one - overlap) + rounding))


def _rounding(terms: int) -> float:
    """Relative rounding allowance of the sums in ``carry``: 2 g_K with K = terms + 16."""
    k = (terms + 16) * _EPS
    return 2.0 * k / (1.0 - k)


_EPS = float(np.finfo(np.float64).eps)


class Prover:
    """The proven λ2 floor of one session's CovGraph and how to renew it (no decisions).

    ``certify`` answers whether λ2 > bound + ``CERTIFICATE_MARGIN`` is proven now: by
    carrying the floor, else (dense form) by a Cholesky certificate aimed above the bound
    so that the new floor lasts, then at the bound itself. ``solved`` takes the figures of a
    decision that ran the eigen-solve: an exact dense solve is itself a floor; after a
    sparse (ARPACK) solve, which proves nothing, one Cholesky certificate may set the floor
    for the decisions that follow (graphs up to ``PROOF_MAX_NODES``).
    """

    def __init__(self, proof_max_nodes: int = PROOF_MAX_NODES) -> None:
        """Start without a floor; graphs up to ``proof_max_nodes`` may be factorized."""
        self._proof_max = proof_max_nodes
        self._floor: Floor | None = None
        self._estimate = 1.0  # where λ2 is expected: the last solve or the last miss
        self._carried = 0  # decisions the current floor settled
        self._skip = 0  # sparse solves left that set no floor
        self._backoff = 1  # the next skip, doubled while floors keep failing at once

    def reset(self) -> None:
        """Forget the floor (the graph was reshaped) and expect a room-like λ2 again."""
        self._floor = None
        self._estimate = 1.0
        self._skip, self._backoff = 0, 1

    def _lost(self) -> None:
        """The floor no longer proves the bound: note whether it was worth its proof."""
        if self._carried == 0:
            self._skip = self._backoff
            self._backoff = min(2 * self._backoff, MAX_SKIPPED_PROOFS)
        else:
            self._backoff = 1
        self._floor = None

    def certify(self, graph: CovGraph, bound: float) -> bool:
        """Return True when λ2 > bound + ``CERTIFICATE_MARGIN`` is proven for the graph."""
        if graph.node_count < DRIFT_MIN_NODES:
            self._floor = None
            return lambda2_exceeds(graph.similarity(), bound)
        if self._floor is not None:
            changes = graph.changes()
            # Carried from the proof itself, not from the last decision: a drift that
            # partly cancels, or moves different nodes' degrees, is not counted twice.
            if changes is not None and carry(self._floor, graph.degrees(), changes) > bound + (
                CERTIFICATE_MARGIN
            ):
                self._carried += 1
                return True
            self._lost()
        if not graph.is_dense:
            return False  # a solve (ARPACK) costs less than a dense proof: see ``solved``
        return self._prove(graph, graph.similarity(), bound, graph.degrees())

    def solved(self, graph: CovGraph, w: Similarity, lambda2: float, bound: float) -> None:
        """Take the λ2 of a solve on W (the graph's) that found no transition."""
        self._estimate = lambda2
        if graph.node_count < DRIFT_MIN_NODES:
            return
        if graph.is_dense:
            # LAPACK's dsyevr is backward stable: its λ2 is within ~n·ε·||L_sym||
            # (||L_sym|| <= 2) of the true one, far inside the margin.
            self._keep(graph, min(lambda2, 2.0) - CERTIFICATE_MARGIN, graph.degrees(), bound)
        elif self._skip > 0:
            self._skip -= 1  # the last floor did not outlast a decision: not worth a proof
        elif graph.node_count <= self._proof_max and lambda2 > bound + MIN_HEADROOM:
            self._prove(graph, w, bound, graph.degrees(), at_bound=False)

    def _prove(
        self,
        graph: CovGraph,
        w: Similarity,
        bound: float,
        degrees: NDArray[np.float64],
        *,
        at_bound: bool = True,
    ) -> bool:
        for _ in range(AIMS):
            if self._estimate <= bound + MIN_HEADROOM:
                break
            shift = bound + REACH * (self._estimate - bound)
            if lambda2_exceeds(w, shift):
                self._keep(graph, shift, degrees, bound)
                return True
            self._estimate = shift  # λ2 is below it: aim lower
        return at_bound and lambda2_exceeds(w, bound)

    def _keep(
        self, graph: CovGraph, lower: float, degrees: NDArray[np.float64], bound: float
    ) -> None:
        if lower <= bound + MIN_HEADROOM:
            return  # a floor at the bound would certify nothing later
        self._floor = Floor(lower, degrees)
        self._carried = 0
        graph.mark()

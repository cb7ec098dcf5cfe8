"""Edge counts a_ij and CovRate W of a CovGraph, in a dense and a sparse form (§3.1).

``CovGraph`` owns the nodes (feature IDs, n_i, first sightings, which nodes a frame touched)
and hands the edges to a ``CountStore``. Two stores implement the same interface:

- ``DenseCounts`` keeps a dense symmetric count matrix and a dense W for small graphs (at
  most ``dense_max_nodes`` nodes, the size of a room's features): a frame adds to its k x k
  block, and a refresh recomputes only the touched rows and columns of W. On graphs of tens
  of nodes this avoids rebuilding scipy.sparse containers at every decision, which cost
  several times the eigen-solve itself (profiled under fleet load).
- ``SparseCounts`` keeps one upper-triangular (i < j) CSR matrix of int64 counts, canonical
  (sorted indices, no duplicates) whenever nothing is pending. Frames append their pairs in
  O(pairs) vectorized numpy and the pending pairs are merged in one vectorized pass before
  anything reads the edges, so a burst of frames (coalesced under load) counts cheaply.

Both hold the same integer counts and compute W_ij = a_ij / min(n_i, n_j) (Eq. 1) with the
same IEEE division, so W is equal to the last bit whichever form holds the graph. Which form
is used is decided by ``CovGraph`` alone; the stores never convert themselves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy import sparse

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from lessmap.core.spectral import Similarity

#: Side of a new dense matrix (and the node capacity of a new CovGraph). Small, because a
#: fleet has thousands of small sessions: 16 nodes hold 3 KiB of matrices where 64 held 48 KiB,
#: and doubling keeps the growth amortized.
INITIAL_CAPACITY = 16


@dataclass(frozen=True, slots=True)
class UpperCounts:
    """a_ij for i < j as canonical CSR arrays (sorted, no duplicates), all int64.

    The exchange format between the stores, and the edge part of a ``CovGraphState``.
    """

    indptr: NDArray[np.int64]  # (n + 1,)
    indices: NDArray[np.int64]  # column j of each entry, ascending within a row
    counts: NDArray[np.int64]  # a_ij of each entry, > 0

    @property
    def nodes(self) -> int:
        """Number of nodes n (rows of the matrix)."""
        return int(self.indptr.size) - 1

    @classmethod
    def empty(cls, nodes: int = 0) -> UpperCounts:
        """No edges among ``nodes`` nodes."""
        none = np.zeros(0, dtype=np.int64)
        return cls(np.zeros(nodes + 1, dtype=np.int64), none, none.copy())

    def csr(self) -> sparse.csr_array:
        """The counts as an (n, n) upper-triangular CSR matrix."""
        n = self.nodes
        return sparse.csr_array((self.counts, self.indices, self.indptr), shape=(n, n))

    @classmethod
    def from_csr(cls, upper: sparse.csr_array) -> UpperCounts:
        """Copy a canonical upper-triangular CSR matrix as int64 arrays.

        scipy narrows index arrays to int32 when the values fit; snapshots want int64.
        """
        return cls(
            upper.indptr.astype(np.int64),
            upper.indices.astype(np.int64),
            upper.data.astype(np.int64),
        )


class CountStore(Protocol):
    """The edges of a CovGraph: counts a_ij and CovRate W, in one storage form.

    Node indices are the CovGraph's. The store learns the node count through ``resize``
    and n_i through ``refresh``; it never sees feature IDs.
    """

    def resize(self, nodes: int) -> None:
        """The graph now has ``nodes`` nodes (only ever more; new nodes have no edges)."""
        ...

    def add_frame(self, nodes: NDArray[np.int64]) -> None:
        """a_ij += 1 for every pair of ``nodes`` (distinct, sorted ascending, < node count)."""
        ...

    def refresh(self, counts: NDArray[np.int64], touched: NDArray[np.bool_]) -> None:
        """Bring W up to date after n_i changed for the ``touched`` nodes (shape (n,) each).

        Entries with no touched endpoint keep their value: Eq. 1 depends on a_ij, n_i and
        n_j only (the paper's incremental update, §3.1 step 3).
        """
        ...

    def similarity(self) -> Similarity:
        """W as of the last ``refresh``, in the store's own form (dense array or CSR)."""
        ...

    def similarity_csr(self) -> sparse.csr_array:
        """W as of the last ``refresh`` as a symmetric CSR float64 matrix."""
        ...

    def similarity_array(self) -> NDArray[np.float64]:
        """W as of the last ``refresh`` as a dense (n, n) array (may be a read-only view)."""
        ...

    def edge_count(self) -> int:
        """Number of pairs with a_ij > 0."""
        ...

    def pair_count(self, i: int, j: int) -> int:
        """a_ij for two distinct node indices."""
        ...

    def upper(self, kept: NDArray[np.int64] | None = None) -> UpperCounts:
        """a_ij as canonical int64 CSR arrays, of all nodes or of ``kept`` (ascending) only."""
        ...


class DenseCounts:
    """Dense symmetric a_ij (int32, zero diagonal) and W, for graphs up to ``limit`` nodes."""

    def __init__(self, nodes: int, limit: int, upper: UpperCounts) -> None:
        """Hold ``upper`` (edges among its nodes) in a graph of ``nodes`` <= ``limit`` nodes."""
        side = min(max(INITIAL_CAPACITY, nodes), limit)
        self._limit = limit
        self._nodes = nodes
        self._counts = np.zeros((side, side), dtype=np.int32)
        self._rates = np.zeros((side, side), dtype=np.float64)
        rows = np.repeat(np.arange(upper.nodes, dtype=np.int64), np.diff(upper.indptr))
        self._counts[rows, upper.indices] = upper.counts
        self._counts[upper.indices, rows] = upper.counts
        self._all_stale = True  # every row of W is computed on the first refresh

    def resize(self, nodes: int) -> None:
        """Grow the matrices by doubling (capped at the limit) when ``nodes`` exceeds their side."""
        side = self._counts.shape[0]
        if nodes > side:
            # Doubling keeps the copies amortized; the limit caps the last step.
            side = min(2 * side, self._limit)
            counts = np.zeros((side, side), dtype=np.int32)
            rates = np.zeros((side, side), dtype=np.float64)
            old = self._counts.shape[0]
            counts[:old, :old] = self._counts
            rates[:old, :old] = self._rates
            self._counts, self._rates = counts, rates
        self._nodes = nodes

    def add_frame(self, nodes: NDArray[np.int64]) -> None:
        """Add one to the frame's k x k block, off the diagonal."""
        # The k x k block through flat indices: half the cost of np.ix_ at k ~ 20.
        side = self._counts.shape[1]
        flat = self._counts.reshape(-1)  # a view: the matrix is C-contiguous
        flat[(nodes * side)[:, None] + nodes] += 1  # nodes are distinct: no lost updates
        flat[nodes * (side + 1)] -= 1  # a feature is not its own neighbour

    def refresh(self, counts: NDArray[np.int64], touched: NDArray[np.bool_]) -> None:
        """Recompute the touched rows and columns of W (all of them after a load)."""
        n = self._nodes
        if self._all_stale:
            rows_of = np.arange(n, dtype=np.int64)
            self._all_stale = False
        else:
            rows_of = np.flatnonzero(touched)
        if rows_of.size:
            rows = self._counts[rows_of, :n] / np.minimum(counts[rows_of, None], counts[None, :])
            self._rates[rows_of, :n] = rows
            self._rates[:n, rows_of] = rows.T

    def similarity(self) -> NDArray[np.float64]:
        """W as a dense read-only view."""
        return self.similarity_array()

    def similarity_csr(self) -> sparse.csr_array:
        """W as a symmetric CSR float64 matrix (a copy)."""
        n = self._nodes
        return sparse.csr_array(self._rates[:n, :n])

    def similarity_array(self) -> NDArray[np.float64]:
        """W as a dense read-only (n, n) view."""
        n = self._nodes
        view = self._rates[:n, :n]
        view.flags.writeable = False
        return view

    def edge_count(self) -> int:
        """Number of pairs with a_ij > 0."""
        n = self._nodes
        return int(np.count_nonzero(self._counts[:n, :n])) // 2

    def pair_count(self, i: int, j: int) -> int:
        """a_ij for two distinct node indices."""
        return int(self._counts[i, j])

    def upper(self, kept: NDArray[np.int64] | None = None) -> UpperCounts:
        """a_ij as canonical int64 CSR arrays, of all nodes or of ``kept`` only."""
        n = self._nodes
        block = self._counts[:n, :n] if kept is None else self._counts[np.ix_(kept, kept)]
        upper = sparse.csr_array(np.triu(block, k=1).astype(np.int64))
        upper.sort_indices()
        return UpperCounts.from_csr(upper)


class SparseCounts:
    """Upper-triangular CSR a_ij (int64) with W aligned to its entries, for any size."""

    def __init__(self, nodes: int, upper: UpperCounts) -> None:
        """Hold ``upper`` (edges among its nodes) in a graph of ``nodes`` nodes."""
        self._nodes = nodes
        self._edges = _csr(upper.counts, upper.indices, upper.indptr, upper.nodes)
        self._rates = np.zeros(0, dtype=np.float64)  # aligned with self._edges.data
        self._pending_rows: list[NDArray[np.int64]] = []
        self._pending_cols: list[NDArray[np.int64]] = []
        self._structure_changed = True  # W is computed in full on the first refresh

    def resize(self, nodes: int) -> None:
        """Record the node count; the CSR matrix is padded on the next merge."""
        self._nodes = nodes  # the CSR matrix is padded when the pending pairs are merged

    def add_frame(self, nodes: NDArray[np.int64]) -> None:
        """Queue the frame's pairs i < j for the next merge."""
        if nodes.size >= 2:
            # All pairs i < j of the frame; nodes is sorted, so triu indices give i < j.
            left, right = np.triu_indices(nodes.size, k=1)
            self._pending_rows.append(nodes[left])
            self._pending_cols.append(nodes[right])

    def _merge(self) -> None:
        """Pad the CSR counts to the node count and merge the pending pairs into them."""
        n = self._nodes
        if self._edges.shape[0] != n:
            # Growing a CSR matrix is padding its indptr: new rows are empty.
            indptr = np.concatenate(
                [self._edges.indptr, np.full(n - self._edges.shape[0], self._edges.nnz)]
            ).astype(np.int64)
            self._edges = sparse.csr_array(
                (self._edges.data, self._edges.indices, indptr), shape=(n, n)
            )
        if not self._pending_rows:
            return
        rows = np.concatenate(self._pending_rows)
        cols = np.concatenate(self._pending_cols)
        self._pending_rows.clear()
        self._pending_cols.clear()
        batch = sparse.coo_array(
            (np.ones(rows.size, dtype=np.int64), (rows, cols)), shape=(n, n)
        ).tocsr()
        old_nnz = self._edges.nnz
        merged = (self._edges + batch).tocsr()
        merged.sum_duplicates()
        merged.sort_indices()
        # New pairs shift the entries, so W's values no longer line up with them.
        self._structure_changed |= merged.nnz != old_nnz
        self._edges = _csr(merged.data, merged.indices, merged.indptr, n)

    def refresh(self, counts: NDArray[np.int64], touched: NDArray[np.bool_]) -> None:
        """Merge the pending pairs and recompute the entries with a touched endpoint."""
        self._merge()
        rows_of_entries = np.repeat(
            np.arange(self._nodes, dtype=np.int64), np.diff(self._edges.indptr)
        )
        cols_of_entries = self._edges.indices
        if self._structure_changed or self._rates.size != self._edges.nnz:
            mask = np.ones(self._edges.nnz, dtype=bool)
            self._rates = np.zeros(self._edges.nnz, dtype=np.float64)
            self._structure_changed = False
        else:
            mask = touched[rows_of_entries] | touched[cols_of_entries]
        r, c = rows_of_entries[mask], cols_of_entries[mask]
        self._rates[mask] = self._edges.data[mask] / np.minimum(counts[r], counts[c])

    def similarity(self) -> sparse.csr_array:
        """W as a symmetric CSR float64 matrix."""
        return self.similarity_csr()

    def similarity_csr(self) -> sparse.csr_array:
        """W as a symmetric CSR float64 matrix."""
        self._merge()
        upper = sparse.csr_array(
            (self._rates.copy(), self._edges.indices, self._edges.indptr), shape=self._edges.shape
        )
        return (upper + upper.T).tocsr()

    def similarity_array(self) -> NDArray[np.float64]:
        """W as a dense (n, n) array (a copy)."""
        dense: NDArray[np.float64] = self.similarity_csr().toarray()
        return dense

    def edge_count(self) -> int:
        """Number of pairs with a_ij > 0."""
        self._merge()
        return int(self._edges.nnz)

    def pair_count(self, i: int, j: int) -> int:
        """a_ij for two distinct node indices."""
        self._merge()
        lo, hi = min(i, j), max(i, j)
        start, stop = self._edges.indptr[lo], self._edges.indptr[lo + 1]
        pos = np.searchsorted(self._edges.indices[start:stop], hi)
        if pos < stop - start and self._edges.indices[start + pos] == hi:
            return int(self._edges.data[start + pos])
        return 0

    def upper(self, kept: NDArray[np.int64] | None = None) -> UpperCounts:
        """a_ij as canonical int64 CSR arrays, of all nodes or of ``kept`` only."""
        self._merge()
        if kept is None:
            return UpperCounts.from_csr(self._edges)
        sub = self._edges[kept][:, kept].tocsr()
        sub.sort_indices()
        return UpperCounts.from_csr(sub)


def _csr(
    data: NDArray[np.integer], indices: NDArray[np.integer], indptr: NDArray[np.integer], n: int
) -> sparse.csr_array:
    # int64 throughout, as snapshots store them (scipy may still narrow the index arrays).
    return sparse.csr_array(
        (
            np.asarray(data, dtype=np.int64),
            np.asarray(indices, dtype=np.int64),
            np.asarray(indptr, dtype=np.int64),
        ),
        shape=(n, n),
    )

"""Edge counts a_ij and CovRate W of a CovGraph, in a dense and a sparse form (§3.1).

``CovGraph`` owns the nodes and hands the edges to a ``CountStore``: ``DenseCounts`` (a dense
count matrix and W, for small graphs and dense ones, where rebuilding sparse containers at
every decision would cost more than the solve) or ``SparseCounts`` (sorted upper-triangular
keys in CSR order, so a burst of coalesced frames counts in O(pairs) and never rebuilds).

Rules of this file:

1. Both stores hold the same integer counts and compute W_ij = a_ij / min(n_i, n_j) (Eq. 1)
   with the same IEEE division, so W is equal to the last bit whichever form holds it.
2. ``CovGraph`` alone decides the form; the stores never convert themselves.
3. Both remember W at a ``mark`` and report the entries changed since (the drift certificate).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy import sparse

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from lessmap.core.paper.spectral import Similarity

#: What the sparse store holds per edge: an int64 key, an int64 count and a float64 W. The
#: service's edge budgets are written in these edges (``CovGraph.memory_edges``).
SPARSE_BYTES_PER_EDGE = 24

#: Side of a new dense matrix (and the node capacity of a new CovGraph). Small, because a
#: fleet has thousands of small sessions; doubling keeps the growth amortized.
INITIAL_CAPACITY = 16

#: Up to this many nodes the dense store recomputes all of W at each refresh rather than the
#: touched rows: whole-block numpy calls beat gathering and scattering rows on small graphs.
FULL_REFRESH_MAX_NODES = 64

#: Above ``FULL_REFRESH_MAX_NODES``, the dense store also recomputes all of W when more than
#: this share of the rows was touched (a frame of hundreds of features): one pass over the
#: block costs less than gathering those rows and scattering them and their transpose.
FULL_REFRESH_SHARE = 0.5

#: Past its doubling limit (``dense_max_nodes``: a small graph's capacity grows by doubling)
#: a dense store grows by this fraction of its side, so its spare capacity stays small: at
#: most (1 + 1/8)² = 1.27 times the n x n block it holds.
GROWTH_ABOVE_DOUBLING = 8


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


@dataclass(frozen=True, slots=True)
class Changes:
    """Entries (i < j) of W that moved since the store's last ``mark``, with both values.

    A pair that was not an edge at the mark had W = 0 then; entries with no change are left
    out. What ``lessmap.core.paper.drift`` needs to bound how far λ2 can have moved.
    """

    rows: NDArray[np.int64]  # i of each entry
    cols: NDArray[np.int64]  # j of each entry, > i
    delta: NDArray[np.float64]  # W_ij now - W_ij at the mark


@dataclass(frozen=True, slots=True)
class BlockChanges:
    """W's changes since the last ``mark`` as dense row blocks (the dense store's ``Changes``).

    Only the rows recomputed since the mark can differ from it, so every changed entry lies
    in ``moved`` (those rows, minus the mark; unchanged entries are 0 there) or in ``new``
    (the rows of the nodes added since, whose entries were 0 at the mark). Each changed
    pair of old nodes appears once or twice (twice when both rows moved); ``entries`` lists
    each pair once. Blocks cost one row gather and one subtraction, where listing the entries
    would cost masks and index arrays several times larger.
    """

    old: int  # nodes at the mark
    rows: NDArray[np.int64]  # old nodes whose row was recomputed since the mark, ascending
    moved: NDArray[np.float64]  # (rows.size, old): W now - W at the mark, on those rows
    new: NDArray[np.float64]  # (n - old, n): W now, on the rows of the nodes added since

    def entries(self) -> Changes:
        """The same changes as one entry (i < j) per changed pair."""
        old, n = self.old, self.new.shape[1] if self.new.size else self.old
        listed = np.zeros(old, dtype=bool)
        listed[self.rows] = True
        # A pair of two moved rows is read from the row of its smaller node only.
        upper = (self.moved != 0.0) & (
            ~listed[None, :] | (np.arange(old)[None, :] > self.rows[:, None])
        )
        at, cols = np.nonzero(upper)
        i, j = self.rows[at], cols
        fresh_at, fresh_cols = np.nonzero(
            (self.new != 0.0) & (np.arange(n)[None, :] < np.arange(old, n)[:, None])
        )
        rows = np.concatenate([np.minimum(i, j), fresh_cols]).astype(np.int64)
        cols_out = np.concatenate([np.maximum(i, j), fresh_at + old]).astype(np.int64)
        delta = np.concatenate([self.moved[at, cols], self.new[fresh_at, fresh_cols]])
        return Changes(rows, cols_out, delta)


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

    def degrees(self) -> NDArray[np.float64]:
        """Row sums of W as of the last ``refresh``, shape (n,)."""
        ...

    def mark(self) -> None:
        """Remember W as of the last ``refresh``, for ``changes``."""
        ...

    def changes(self) -> Changes | BlockChanges | None:
        """What of W differs from the last ``mark``; None before any mark."""
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
    """Dense symmetric a_ij (int32, zero diagonal) and W, for graphs up to ``limit`` nodes.

    Memory: 12 B per cell of its (side x side) matrices (int32 count, float64 W), i.e. 24 B
    per pair of nodes whether or not it is an edge, plus 8 B per cell of n x n at a mark.
    """

    def __init__(
        self,
        nodes: int,
        limit: int,
        upper: UpperCounts,
        *,
        full_refresh_max_nodes: int = FULL_REFRESH_MAX_NODES,
        doubling_max: int | None = None,
    ) -> None:
        """Hold ``upper`` (edges among its nodes) in a graph of ``nodes`` <= ``limit`` nodes.

        The capacity doubles up to ``doubling_max`` nodes (default ``limit``) and grows by
        1/``GROWTH_ABOVE_DOUBLING`` above.
        """
        side = min(max(INITIAL_CAPACITY, nodes), limit)
        self._limit = limit
        self._doubling_max = limit if doubling_max is None else doubling_max
        self._full_refresh_max_nodes = full_refresh_max_nodes
        self._nodes = nodes
        self._counts = np.zeros((side, side), dtype=np.int32)
        self._rates = np.zeros((side, side), dtype=np.float64)
        rows = np.repeat(np.arange(upper.nodes, dtype=np.int64), np.diff(upper.indptr))
        self._counts[rows, upper.indices] = upper.counts
        self._counts[upper.indices, rows] = upper.counts
        # Kept up to date by ``add_frame``: the service's budgets read the edges after each
        # decision, and counting a whole block each time costs more than the decision.
        self._edges = int(np.count_nonzero(upper.counts))
        self._marked: NDArray[np.float64] | None = None  # W at the last ``mark``
        self._moved = np.zeros(side, dtype=bool)  # rows recomputed since the mark
        self._all_stale = True  # every row of W is computed on the first refresh

    def resize(self, nodes: int) -> None:
        """Grow the matrices (capped at the limit) when ``nodes`` exceeds their side."""
        side = self._counts.shape[0]
        if nodes > side:
            # Doubling keeps the copies amortized; past the doubling limit a smaller step
            # keeps the spare capacity of a large matrix small (the copies stay amortized:
            # one per side/8 new nodes). The limit caps the last step.
            if side < self._doubling_max:
                grown = min(2 * side, self._doubling_max)
            else:
                grown = side + side // GROWTH_ABOVE_DOUBLING
            side = min(max(grown, nodes), self._limit)
            counts = np.zeros((side, side), dtype=np.int32)
            rates = np.zeros((side, side), dtype=np.float64)
            old = self._counts.shape[0]
            counts[:old, :old] = self._counts
            rates[:old, :old] = self._rates
            moved = np.zeros(side, dtype=bool)
            moved[:old] = self._moved
            self._counts, self._rates, self._moved = counts, rates, moved
        self._nodes = nodes

    def add_frame(self, nodes: NDArray[np.int64]) -> None:
        """Add one to the frame's k x k block, off the diagonal."""
        # The k x k block through flat indices: cheaper than np.ix_ at a frame's size.
        side = self._counts.shape[1]
        flat = self._counts.reshape(-1)  # a view: the matrix is C-contiguous
        at = (nodes * side)[:, None] + nodes
        block = flat[at]
        # Pairs at 0 become edges; the k diagonal entries are always 0 and are not pairs.
        self._edges += (int(np.count_nonzero(block == 0)) - nodes.size) // 2
        block += 1
        block.reshape(-1)[:: nodes.size + 1] = 0  # a feature is not its own neighbour
        flat[at] = block  # nodes are distinct: no lost updates

    def refresh(self, counts: NDArray[np.int64], touched: NDArray[np.bool_]) -> None:
        """Recompute the touched rows and columns of W (all of them after a load)."""
        n = self._nodes
        if n <= self._full_refresh_max_nodes:
            # A fleet's sessions are mostly tens of nodes: there whole-block numpy calls cost
            # less than gathering and scattering the touched rows. Same integers, same
            # division: the entries that did not move keep their exact values. Every row
            # counts as moved (a superset).
            np.divide(
                self._counts[:n, :n], np.minimum.outer(counts, counts), out=self._rates[:n, :n]
            )
            self._moved[:n] = True
            self._all_stale = False
            return
        if self._all_stale:
            rows_of = np.arange(n, dtype=np.int64)
            self._all_stale = False
        else:
            rows_of = np.flatnonzero(touched)
        if rows_of.size > FULL_REFRESH_SHARE * n:
            # Most rows moved (a frame of hundreds of features): the whole block at once,
            # same integers, same division, so the rows that did not move keep their values
            # (n_i as float64 are the same integers: a quarter cheaper than int64 minima).
            as_float = counts.astype(np.float64)
            np.divide(
                self._counts[:n, :n], np.minimum.outer(as_float, as_float), out=self._rates[:n, :n]
            )
            self._moved[:n] = True
        elif rows_of.size:
            self._moved[rows_of] = True
            rows = self._counts[rows_of, :n] / np.minimum(counts[rows_of, None], counts[None, :])
            self._rates[rows_of, :n] = rows
            self._rates[:n, rows_of] = rows.T

    def similarity(self) -> NDArray[np.float64]:
        """W as a dense read-only view."""
        return self.similarity_array()

    def similarity_csr(self) -> sparse.csr_array:
        """W as a symmetric CSR float64 matrix (a copy): the sparse store's, array for array.

        The edges are the nonzero counts, in row-major order (sorted columns), with int64
        index arrays like ``SparseCounts.similarity_csr``: the same CSR, so the same ARPACK
        solve. Built from flat positions (about a third of ``csr_array(dense)``'s cost).
        """
        n = self._nodes
        side = self._counts.shape[1]
        # The first n rows are contiguous and hold no edge beyond column n, so the flat
        # positions of their nonzero counts are the edges' cells in row-major order.
        edges = self._counts[:n].reshape(-1) != 0
        per_row = np.count_nonzero(edges.reshape(n, side), axis=1)
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(per_row, out=indptr[1:])
        at = np.flatnonzero(edges)
        data = self._rates.reshape(-1).take(at)
        cols = at - np.repeat(np.arange(0, n * side, side, dtype=np.int64), per_row)
        return sparse.csr_array((data, cols, indptr), shape=(n, n))

    def similarity_array(self) -> NDArray[np.float64]:
        """W as a dense read-only (n, n) view."""
        n = self._nodes
        view = self._rates[:n, :n]
        view.flags.writeable = False
        return view

    def degrees(self) -> NDArray[np.float64]:
        """Row sums of W, shape (n,), as one matrix-vector product.

        BLAS sums in another order than the spectral code's ``w.sum(axis=1)``, at half its
        cost; the two agree to rounding (g_n relative), which is all the floor assumes of
        the degrees it is handed (``lessmap.core.paper.drift``). Decisions never read these.
        """
        n = self._nodes
        degrees: NDArray[np.float64] = self._rates[:n, :n] @ np.ones(n)
        return degrees

    def mark(self) -> None:
        """Remember W as it stands, for ``changes``."""
        n = self._nodes
        self._marked = self._rates[:n, :n].copy()
        self._moved[:] = False

    def changes(self) -> BlockChanges | None:
        """The rows of W that may differ from the last ``mark`` (None before any mark)."""
        if self._marked is None:
            return None
        n, old = self._nodes, self._marked.shape[0]
        # Only rows recomputed since the mark (and nodes added since) can have moved.
        rows = np.flatnonzero(self._moved[:old])
        moved = self._rates[rows, :old]
        moved -= self._marked[rows]
        new = self._rates[old:n, :n]
        new.flags.writeable = False
        return BlockChanges(old, rows, moved, new)

    def edge_count(self) -> int:
        """Number of pairs with a_ij > 0."""
        return self._edges

    def held_bytes(self) -> int:
        """Bytes of the matrices (every cell, edge or not) and of W at the mark."""
        marked = 0 if self._marked is None else self._marked.nbytes
        return self._counts.nbytes + self._rates.nbytes + marked

    def pair_count(self, i: int, j: int) -> int:
        """a_ij for two distinct node indices."""
        return int(self._counts[i, j])

    def upper(self, kept: NDArray[np.int64] | None = None) -> UpperCounts:
        """a_ij as canonical int64 CSR arrays, of all nodes or of ``kept`` only."""
        n = self._nodes
        block = self._counts[:n, :n] if kept is None else self._counts[np.ix_(kept, kept)]
        # Straight from the dense block (every checkpoint asks): nonzero walks it in row-major
        # order, so the entries come out in canonical CSR order with no sparse matrix built.
        rows, cols = np.nonzero(np.triu(block, k=1))
        indptr = np.zeros(block.shape[0] + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows, minlength=block.shape[0]), out=indptr[1:])
        return UpperCounts(indptr, cols.astype(np.int64), block[rows, cols].astype(np.int64))


class SparseCounts:
    """Upper-triangular a_ij (int64) with W aligned to its entries, for any size.

    Entries are kept in one sorted array of keys ``i << 32 | j`` (i < j: the CSR order), with
    the counts and W values aligned to it. A merge finds the pending pairs by binary search:
    pairs already counted are incremented in place and only new pairs are inserted, so a
    frame costs O(its pairs · log edges) plus one shifting copy when it brings new pairs,
    instead of rebuilding the matrix. The CSR arrays are derived from the keys when a caller
    asks for them.
    """

    def __init__(self, nodes: int, upper: UpperCounts) -> None:
        """Hold ``upper`` (edges among its nodes) in a graph of ``nodes`` nodes."""
        self._nodes = nodes
        rows = np.repeat(np.arange(upper.nodes, dtype=np.int64), np.diff(upper.indptr))
        self._keys = (rows << _KEY_SHIFT) | np.asarray(upper.indices, dtype=np.int64)
        self._counts = np.array(upper.counts, dtype=np.int64)
        self._rates = np.zeros(self._keys.size, dtype=np.float64)
        self._marked: NDArray[np.float64] | None = None  # W at the last ``mark``
        self._pending_rows: list[NDArray[np.int64]] = []
        self._pending_cols: list[NDArray[np.int64]] = []
        self._all_stale = True  # W is computed in full on the first refresh
        self._cols: NDArray[np.int64] | None = None  # j of each key, refresh to next read

    def resize(self, nodes: int) -> None:
        """Record the node count (new nodes have no entries)."""
        self._nodes = nodes

    def add_frame(self, nodes: NDArray[np.int64]) -> None:
        """Queue the frame's pairs i < j for the next merge."""
        if nodes.size >= 2:
            # All pairs i < j of the frame; nodes is sorted, so triu indices give i < j.
            left, right = np.triu_indices(nodes.size, k=1)
            self._pending_rows.append(nodes[left])
            self._pending_cols.append(nodes[right])

    def _merge(self) -> None:
        """Add the pending pairs to the counts: in place where known, inserted where new."""
        if not self._pending_rows:
            return
        keys = (np.concatenate(self._pending_rows) << _KEY_SHIFT) | np.concatenate(
            self._pending_cols
        )
        single = len(self._pending_rows) == 1
        self._pending_rows.clear()
        self._pending_cols.clear()
        if single:
            # One frame's pairs: its nodes are sorted and distinct and triu_indices lists
            # the pairs row by row, so the keys are already strictly ascending.
            distinct, repeats = keys, np.ones(keys.size, dtype=np.int64)
        else:
            keys.sort()
            starts = np.flatnonzero(np.concatenate(([True], keys[1:] != keys[:-1])))
            distinct = keys[starts]
            repeats = np.diff(np.append(starts, keys.size))
        at = np.searchsorted(self._keys, distinct)
        if self._keys.size:
            # A key beyond the last one compares with the last (smaller) key: not known.
            known = self._keys[np.minimum(at, self._keys.size - 1)] == distinct
        else:
            known = np.zeros(distinct.size, dtype=bool)
        self._counts[at[known]] += repeats[known]  # distinct keys: no lost updates
        fresh = ~known
        if fresh.any():
            # New pairs have a touched endpoint, so the next refresh computes their W.
            where = at[fresh]
            self._keys = np.insert(self._keys, where, distinct[fresh])
            self._cols = None
            self._counts = np.insert(self._counts, where, repeats[fresh])
            self._rates = np.insert(self._rates, where, 0.0)
            if self._marked is not None:
                self._marked = np.insert(self._marked, where, 0.0)

    def _rows_cols(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        return self._keys >> _KEY_SHIFT, self._columns()

    def _columns(self, *, release: bool = False) -> NDArray[np.int64]:
        # A refresh keeps them for the decision's next read of W (its degrees or its CSR),
        # which releases them: a pass over the keys costs as much as the rest of a carried
        # decision, and 8 B per edge held between decisions would raise the session's RSS.
        cols = self._cols if self._cols is not None else self._keys & _COL_MASK
        self._cols = None if release else cols
        return cols

    def _indptr(self) -> NDArray[np.int64]:
        bounds = np.arange(self._nodes + 1, dtype=np.int64) << _KEY_SHIFT
        indptr: NDArray[np.int64] = np.searchsorted(self._keys, bounds).astype(np.int64)
        return indptr

    def refresh(self, counts: NDArray[np.int64], touched: NDArray[np.bool_]) -> None:
        """Merge the pending pairs and recompute the entries with a touched endpoint."""
        self._merge()
        if self._all_stale:
            self._all_stale = False
            rows, cols = self._rows_cols()
            self._rates = self._counts / np.minimum(counts[rows], counts[cols])
            return
        cols = self._columns()
        # Entries of a touched row are its CSR segment: repeat the row's flag over it
        # instead of shifting every key to find its row.
        moved = np.repeat(touched, np.diff(self._indptr()))
        moved |= touched[cols]
        at = np.flatnonzero(moved)
        if 4 * at.size > moved.size:
            # Most entries moved (a frame of hundreds of features): one pass over all of
            # them beats gathering and scattering. Same integers, same division, so the
            # entries that did not move keep their exact values.
            rows = self._keys >> _KEY_SHIFT
            np.divide(self._counts, np.minimum(counts[rows], counts[cols]), out=self._rates)
            return
        r, c = self._keys[at] >> _KEY_SHIFT, cols[at]
        self._rates[at] = self._counts[at] / np.minimum(counts[r], counts[c])

    def similarity(self) -> sparse.csr_array:
        """W as a symmetric CSR float64 matrix."""
        return self.similarity_csr()

    def similarity_csr(self) -> sparse.csr_array:
        """W as a symmetric CSR float64 matrix."""
        self._merge()
        n = self._nodes
        upper = sparse.csr_array(
            (self._rates.copy(), self._columns(release=True), self._indptr()), shape=(n, n)
        )
        symmetric: sparse.csr_array = (upper + upper.T).tocsr()
        return symmetric

    def similarity_array(self) -> NDArray[np.float64]:
        """W as a dense (n, n) array (a copy)."""
        dense: NDArray[np.float64] = self.similarity_csr().toarray()
        return dense

    def degrees(self) -> NDArray[np.float64]:
        """Row sums of W as of the last ``refresh``, shape (n,)."""
        n = self._nodes
        both = np.bincount(self._columns(release=True), self._rates, n)  # lower triangle
        # The upper triangle's row sums, one CSR segment each (empty rows add nothing):
        # reduceat instead of a bincount over every key's row.
        starts = self._indptr()
        filled = np.flatnonzero(starts[1:] > starts[:-1])
        if filled.size:
            both[filled] += np.add.reduceat(self._rates, starts[filled])
        return np.asarray(both, dtype=np.float64)

    def mark(self) -> None:
        """Remember W as it stands, for ``changes``."""
        self._marked = self._rates.copy()

    def changes(self) -> Changes | None:
        """The entries of W that differ from the last ``mark`` (None before any mark)."""
        if self._marked is None:
            return None
        moved = np.flatnonzero(self._rates != self._marked)
        keys = self._keys[moved]
        return Changes(
            keys >> _KEY_SHIFT, keys & _COL_MASK, self._rates[moved] - self._marked[moved]
        )

    def edge_count(self) -> int:
        """Number of pairs with a_ij > 0."""
        self._merge()
        return int(self._keys.size)

    def pair_count(self, i: int, j: int) -> int:
        """a_ij for two distinct node indices."""
        self._merge()
        key = (min(i, j) << _KEY_SHIFT) | max(i, j)
        pos = int(np.searchsorted(self._keys, key))
        if pos < self._keys.size and self._keys[pos] == key:
            return int(self._counts[pos])
        return 0

    def upper(self, kept: NDArray[np.int64] | None = None) -> UpperCounts:
        """a_ij as canonical int64 CSR arrays, of all nodes or of ``kept`` only."""
        self._merge()
        whole = UpperCounts(self._indptr(), self._keys & _COL_MASK, self._counts.copy())
        if kept is None:
            return whole
        sub = whole.csr()[kept][:, kept].tocsr()
        sub.sort_indices()
        return UpperCounts.from_csr(sub)


#: Entry keys are ``i << 32 | j``: node indices stay below 2**31 (int64 IDs, memory).
_KEY_SHIFT = 32
_COL_MASK = (1 << _KEY_SHIFT) - 1

"""CovGraph: the covisibility graph of one robot session (LESS-mapping §3.1).

Invariants kept by this module:

- Node i is a feature; ``counts[i]`` = n_i, the number of frames in which it was seen.
- Edge counts a_ij live in one upper-triangular (i < j) CSR matrix of int64 counts,
  canonical (sorted indices, no duplicates) whenever ``_pending`` is empty. Frames append
  their pairs to ``_pending`` in O(pairs) vectorized numpy; the pending pairs are merged into
  the CSR matrix in one vectorized pass before anything reads the edges. That is what makes a
  burst of frames (coalesced under load) cheap: counting never waits for the spectral step.
- The CovRate values W_ij = a_ij / min(n_i, n_j) (Eq. 1) are kept aligned with the CSR
  structure. A frame changes n_i and a_ij only for its own features, so only entries with an
  endpoint among the touched nodes are recomputed; untouched entries keep their values.
- Small graphs (at most ``dense_max_nodes`` nodes, the size of a room's features) keep a
  dense symmetric count matrix and a dense CovRate matrix instead: a frame adds to its
  k x k block, and reading refreshes only the touched rows and columns of W. On graphs of
  tens of nodes this avoids rebuilding scipy.sparse containers at every decision, which
  cost several times the eigen-solve itself (profiled under fleet load). A graph that
  outgrows the limit switches to the sparse form for good (``keep_only`` may switch back).
  Both forms hold the same integer counts and compute W with the same formula.
- Node indices follow first appearance and never change except through ``keep_only``;
  together with integer counts this makes the state reproducible bit for bit after a
  snapshot and restore.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import sparse

from lessmap.core.errors import GraphError

if TYPE_CHECKING:
    from collections.abc import Iterable

    from numpy.typing import NDArray

_INITIAL_CAPACITY = 64


@dataclass(frozen=True, slots=True)
class CovGraphState:
    """Everything a CovGraph holds, as plain arrays (for snapshots)."""

    feature_ids: NDArray[np.int64]  # (n,) feature ID of each node
    counts: NDArray[np.int64]  # (n,) n_i
    first_seen: NDArray[np.int64]  # (n,) seq of the first frame that saw the node
    edge_indptr: NDArray[np.int64]  # upper-triangular CSR of a_ij, shape (n, n)
    edge_indices: NDArray[np.int64]
    edge_counts: NDArray[np.int64]


class CovGraph:
    """Incremental covisibility counts n_i and a_ij with the CovRate similarity W."""

    def __init__(self, dense_max_nodes: int = 400) -> None:
        self._dense_max = dense_max_nodes
        self._dense: NDArray[np.int32] | None = None  # counts a_ij, symmetric, zero diagonal
        self._dense_rates: NDArray[np.float64] | None = None  # W, same shape
        if dense_max_nodes > 0:
            side = min(_INITIAL_CAPACITY, dense_max_nodes)
            self._dense = np.zeros((side, side), dtype=np.int32)
            self._dense_rates = np.zeros((side, side), dtype=np.float64)
        self._index: dict[int, int] = {}
        self._ids = np.zeros(_INITIAL_CAPACITY, dtype=np.int64)
        self._counts = np.zeros(_INITIAL_CAPACITY, dtype=np.int64)
        self._first_seen = np.zeros(_INITIAL_CAPACITY, dtype=np.int64)
        self._size = 0
        self._edges = sparse.csr_array((0, 0), dtype=np.int64)
        self._rates = np.zeros(0, dtype=np.float64)  # aligned with self._edges.data
        self._pending_rows: list[NDArray[np.int64]] = []
        self._pending_cols: list[NDArray[np.int64]] = []
        self._touched = np.zeros(_INITIAL_CAPACITY, dtype=bool)
        self._rates_stale = False

    # -- size ------------------------------------------------------------------------------

    @property
    def node_count(self) -> int:
        """Number of features (nodes)."""
        return self._size

    @property
    def is_dense(self) -> bool:
        """Whether the graph is held in the dense small-graph form."""
        return self._dense is not None

    @property
    def edge_count(self) -> int:
        """Number of covisible pairs (undirected edges)."""
        if self._dense is not None:
            n = self._size
            return int(np.count_nonzero(self._dense[:n, :n])) // 2
        self._flush()
        return int(self._edges.nnz)

    @property
    def feature_ids(self) -> NDArray[np.int64]:
        """Feature ID of each node, by node index (a read-only view)."""
        view = self._ids[: self._size]
        view.flags.writeable = False
        return view

    @property
    def counts(self) -> NDArray[np.int64]:
        """n_i of each node, by node index (a read-only view)."""
        view = self._counts[: self._size]
        view.flags.writeable = False
        return view

    @property
    def first_seen(self) -> NDArray[np.int64]:
        """Seq of the frame in which each node was first seen (a read-only view)."""
        view = self._first_seen[: self._size]
        view.flags.writeable = False
        return view

    def nodes_of(self, features: Iterable[int]) -> NDArray[np.int64]:
        """Return the node indices of the known features among ``features``."""
        found = [self._index[f] for f in features if f in self._index]
        return np.asarray(found, dtype=np.int64)

    # -- update ----------------------------------------------------------------------------

    def add_frame(self, seq: int, features: Iterable[int]) -> NDArray[np.int64]:
        """Count one frame: n_i += 1 per feature, a_ij += 1 per pair (§3.1).

        Duplicate IDs within a frame count once; an empty frame changes nothing.

        Returns:
            The node indices of the frame's distinct features, sorted ascending.
        """
        nodes = self._intern(features, seq)
        if nodes.size == 0:
            return nodes
        self._counts[nodes] += 1
        self._touched[nodes] = True
        self._rates_stale = True
        if self._dense is not None:
            # The k x k block through flat indices: half the cost of np.ix_ at k ~ 20.
            side = self._dense.shape[1]
            flat = self._dense.reshape(-1)  # a view: the matrix is C-contiguous
            flat[(nodes * side)[:, None] + nodes] += 1  # nodes are distinct: no lost updates
            flat[nodes * (side + 1)] -= 1  # a feature is not its own neighbour
        elif nodes.size >= 2:
            # All pairs i < j of the frame; nodes is sorted, so triu indices give i < j.
            left, right = np.triu_indices(nodes.size, k=1)
            self._pending_rows.append(nodes[left])
            self._pending_cols.append(nodes[right])
        return nodes

    def _intern(self, features: Iterable[int], seq: int) -> NDArray[np.int64]:
        index = self._index
        nodes: set[int] = set()
        for feature in features:
            node = index.get(feature)
            if node is None:
                node = self._new_node(int(feature), seq)
            nodes.add(node)
        return np.fromiter(sorted(nodes), dtype=np.int64, count=len(nodes))

    def _new_node(self, feature: int, seq: int) -> int:
        if self._dense is not None:
            if self._size == self._dense_max:
                self._to_sparse()
            elif self._size == self._dense.shape[0]:
                self._grow_dense(min(2 * self._dense.shape[0], self._dense_max))
        if self._size == self._ids.size:
            self._grow(2 * self._ids.size)
        node = self._size
        self._ids[node] = feature
        self._counts[node] = 0
        self._first_seen[node] = seq
        self._touched[node] = False
        self._index[feature] = node
        self._size += 1
        return node

    def _grow(self, capacity: int) -> None:
        for name in ("_ids", "_counts", "_first_seen", "_touched"):
            old = getattr(self, name)
            new = np.zeros(capacity, dtype=old.dtype)
            new[: old.size] = old
            setattr(self, name, new)

    def _grow_dense(self, side: int) -> None:
        assert self._dense is not None
        assert self._dense_rates is not None
        old = self._dense.shape[0]
        counts = np.zeros((side, side), dtype=np.int32)
        counts[:old, :old] = self._dense
        rates = np.zeros((side, side), dtype=np.float64)
        rates[:old, :old] = self._dense_rates
        self._dense, self._dense_rates = counts, rates

    def _to_sparse(self) -> None:
        """Move the counts into the CSR form, for good (the graph outgrew the dense limit)."""
        assert self._dense is not None
        n = self._size
        upper = sparse.csr_array(np.triu(self._dense[:n, :n], k=1).astype(np.int64))
        upper.sort_indices()
        self._edges = sparse.csr_array(
            (
                upper.data.astype(np.int64),
                upper.indices.astype(np.int64),
                upper.indptr.astype(np.int64),
            ),
            shape=(n, n),
        )
        self._dense = None
        self._dense_rates = None
        self._pending_rows.clear()
        self._pending_cols.clear()
        self._rates = np.zeros(0, dtype=np.float64)
        self._rates_stale = True

    def _flush_dense(self) -> None:
        """Refresh W (Eq. 1) in the rows and columns of the nodes touched since last read."""
        assert self._dense is not None
        assert self._dense_rates is not None
        if not self._rates_stale:
            return
        n = self._size
        touched = np.flatnonzero(self._touched[:n])
        if touched.size:
            counts = self._counts[:n]
            rows = self._dense[touched, :n] / np.minimum(counts[touched, None], counts[None, :])
            self._dense_rates[touched, :n] = rows
            self._dense_rates[:n, touched] = rows.T
        self._touched[:n] = False
        self._rates_stale = False

    def _flush(self) -> None:
        """Merge pending pairs into the CSR counts and refresh the touched CovRates."""
        if self._dense is not None:
            self._flush_dense()
            return
        n = self._size
        if self._edges.shape[0] != n:
            # Growing a CSR matrix is padding its indptr: new rows are empty.
            indptr = np.concatenate(
                [self._edges.indptr, np.full(n - self._edges.shape[0], self._edges.nnz)]
            ).astype(np.int64)
            self._edges = sparse.csr_array(
                (self._edges.data, self._edges.indices, indptr), shape=(n, n)
            )
        structure_changed = False
        if self._pending_rows:
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
            structure_changed = merged.nnz != old_nnz
            self._edges = sparse.csr_array(
                (
                    merged.data.astype(np.int64),
                    merged.indices.astype(np.int64),
                    merged.indptr.astype(np.int64),
                ),
                shape=(n, n),
            )
        if not self._rates_stale:
            return
        rows_of_entries = self._row_of_entries()
        cols_of_entries = self._edges.indices
        if structure_changed or self._rates.size != self._edges.nnz:
            mask = np.ones(self._edges.nnz, dtype=bool)
            self._rates = np.zeros(self._edges.nnz, dtype=np.float64)
        else:
            # Eq. 1 depends on a_ij, n_i, n_j only: entries with no touched endpoint keep
            # their value (the paper's incremental update, §3.1 step 3).
            mask = self._touched[rows_of_entries] | self._touched[cols_of_entries]
        r, c = rows_of_entries[mask], cols_of_entries[mask]
        self._rates[mask] = self._edges.data[mask] / np.minimum(self._counts[r], self._counts[c])
        self._touched[:n] = False
        self._rates_stale = False

    def _row_of_entries(self) -> NDArray[np.int64]:
        return np.repeat(np.arange(self._size, dtype=np.int64), np.diff(self._edges.indptr))

    # -- read ------------------------------------------------------------------------------

    def covrate_dense(self) -> NDArray[np.float64]:
        """Return W (Eq. 1) as a dense (n, n) array (a read-only view in the dense form)."""
        if self._dense_rates is None:
            dense: NDArray[np.float64] = self.covrate().toarray()
            return dense
        self._flush()
        view = self._dense_rates[: self._size, : self._size]
        view.flags.writeable = False
        return view

    def covrate(self) -> sparse.csr_array:
        """Return W (Eq. 1): symmetric CSR float64, shape (n, n), zero diagonal, in [0, 1]."""
        if self._dense_rates is not None:
            self._flush()
            n = self._size
            return sparse.csr_array(self._dense_rates[:n, :n])
        self._flush()
        upper = sparse.csr_array(
            (self._rates.copy(), self._edges.indices, self._edges.indptr), shape=self._edges.shape
        )
        return (upper + upper.T).tocsr()

    def edge_counts(self) -> sparse.csr_array:
        """Return a_ij as a symmetric CSR int64 matrix, shape (n, n)."""
        if self._dense is not None:
            n = self._size
            return sparse.csr_array(self._dense[:n, :n].astype(np.int64))
        self._flush()
        return (self._edges + self._edges.T).tocsr()

    def pair_count(self, feature_a: int, feature_b: int) -> int:
        """Return a_ij for two feature IDs (0 when either is unknown or they never met)."""
        i, j = self._index.get(feature_a), self._index.get(feature_b)
        if i is None or j is None or i == j:
            return 0
        if self._dense is not None:
            return int(self._dense[i, j])
        self._flush()
        lo, hi = min(i, j), max(i, j)
        start, stop = self._edges.indptr[lo], self._edges.indptr[lo + 1]
        pos = np.searchsorted(self._edges.indices[start:stop], hi)
        if pos < stop - start and self._edges.indices[start + pos] == hi:
            return int(self._edges.data[start + pos])
        return 0

    def count(self, feature: int) -> int:
        """Return n_i for a feature ID (0 when unknown)."""
        node = self._index.get(feature)
        return 0 if node is None else int(self._counts[node])

    # -- reshape ---------------------------------------------------------------------------

    def keep_only(self, nodes: NDArray[np.int64]) -> None:
        """Drop every node not in ``nodes`` with its edges; keep counts among the rest.

        Node indices are renumbered in their old order, so the result is deterministic.
        """
        self._flush()
        keep = np.zeros(self._size, dtype=bool)
        keep[nodes] = True
        kept = np.flatnonzero(keep)
        if self._dense is not None:
            sub = sparse.csr_array(np.triu(self._dense[np.ix_(kept, kept)], k=1).astype(np.int64))
        else:
            sub = self._edges[kept][:, kept].tocsr()
        sub.sort_indices()
        state = CovGraphState(
            feature_ids=self._ids[kept].copy(),
            counts=self._counts[kept].copy(),
            first_seen=self._first_seen[kept].copy(),
            edge_indptr=sub.indptr.astype(np.int64),
            edge_indices=sub.indices.astype(np.int64),
            edge_counts=sub.data.astype(np.int64),
        )
        self._load(state)

    # -- snapshot --------------------------------------------------------------------------

    def state(self) -> CovGraphState:
        """Return a copy of the whole graph as arrays (always the CSR form)."""
        if self._dense is not None:
            n = self._size
            upper = sparse.csr_array(np.triu(self._dense[:n, :n], k=1).astype(np.int64))
            upper.sort_indices()
            return CovGraphState(
                feature_ids=self._ids[:n].copy(),
                counts=self._counts[:n].copy(),
                first_seen=self._first_seen[:n].copy(),
                edge_indptr=upper.indptr.astype(np.int64),
                edge_indices=upper.indices.astype(np.int64),
                edge_counts=upper.data.astype(np.int64),
            )
        self._flush()
        return CovGraphState(
            feature_ids=self._ids[: self._size].copy(),
            counts=self._counts[: self._size].copy(),
            first_seen=self._first_seen[: self._size].copy(),
            edge_indptr=self._edges.indptr.astype(np.int64),
            edge_indices=self._edges.indices.astype(np.int64),
            edge_counts=self._edges.data.astype(np.int64),
        )

    @classmethod
    def from_state(cls, state: CovGraphState, dense_max_nodes: int = 400) -> CovGraph:
        """Rebuild a graph from ``state()``; later updates match the original exactly."""
        graph = cls(dense_max_nodes)
        graph._load(state)
        return graph

    def _load(self, state: CovGraphState) -> None:
        n = int(state.feature_ids.size)
        if not (state.counts.size == state.first_seen.size == n):
            msg = f"inconsistent CovGraph state: {n} ids, {state.counts.size} counts"
            raise GraphError(msg)
        if state.edge_indptr.size != n + 1:
            msg = f"inconsistent CovGraph state: indptr of {state.edge_indptr.size} for {n} nodes"
            raise GraphError(msg)
        indptr, indices = state.edge_indptr, state.edge_indices
        if (
            indptr[0] != 0
            or indptr[-1] != indices.size
            or state.edge_counts.size != indices.size
            or (indptr.size > 1 and (np.diff(indptr) < 0).any())
            or (indices.size and (indices.min() < 0 or indices.max() >= n))
            or (state.counts < 0).any()
        ):
            msg = "inconsistent CovGraph state: malformed edge arrays"
            raise GraphError(msg)
        capacity = max(_INITIAL_CAPACITY, n)
        self._ids = np.zeros(capacity, dtype=np.int64)
        self._counts = np.zeros(capacity, dtype=np.int64)
        self._first_seen = np.zeros(capacity, dtype=np.int64)
        self._touched = np.zeros(capacity, dtype=bool)
        self._ids[:n] = state.feature_ids
        self._counts[:n] = state.counts
        self._first_seen[:n] = state.first_seen
        self._size = n
        self._index = {int(f): i for i, f in enumerate(state.feature_ids.tolist())}
        if len(self._index) != n:
            msg = "inconsistent CovGraph state: repeated feature IDs"
            raise GraphError(msg)
        self._edges = sparse.csr_array(
            (
                np.asarray(state.edge_counts, dtype=np.int64),
                np.asarray(state.edge_indices, dtype=np.int64),
                np.asarray(state.edge_indptr, dtype=np.int64),
            ),
            shape=(n, n),
        )
        self._pending_rows = []
        self._pending_cols = []
        self._rates = np.zeros(0, dtype=np.float64)
        self._rates_stale = True  # recomputed in full: same formula, same values
        self._dense = self._dense_rates = None
        if n <= self._dense_max and self._dense_max > 0:
            side = min(max(_INITIAL_CAPACITY, n), self._dense_max)
            counts = np.zeros((side, side), dtype=np.int32)
            coo = self._edges.tocoo()
            counts[coo.row, coo.col] = coo.data
            counts[coo.col, coo.row] = coo.data
            self._dense = counts
            self._dense_rates = np.zeros((side, side), dtype=np.float64)
            self._touched[:n] = True  # every row of W is computed on first read

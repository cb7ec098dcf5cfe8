"""CovGraph: the covisibility graph of one robot session (LESS-mapping §3.1).

Rules of this file:

1. Node i is a feature; ``counts[i]`` = n_i, the number of frames in which it was seen.
2. Edge counts a_ij and W_ij = a_ij / min(n_i, n_j) (Eq. 1) live in a ``CountStore``
   (``lessmap.core.paper.counts``); ``_fit_store`` is the only place that picks the store.
   W reaches the solver as a dense array exactly when the graph has at most
   ``dense_max_nodes`` nodes (``is_dense``), whichever store holds it: the store never
   changes a decision.
3. A frame changes n_i and a_ij only for its own features; W is recomputed only at entries
   with a touched endpoint, the next time it is read (coalesced frames count cheaply).
4. Node indices follow first appearance and never change except through ``keep_only``, so
   the state is reproducible bit for bit after a snapshot and restore.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core.errors import GraphError
from lessmap.core.paper.counts import (
    INITIAL_CAPACITY,
    SPARSE_BYTES_PER_EDGE,
    DenseCounts,
    SparseCounts,
    UpperCounts,
)

#: Dense graphs are held in the dense store up to this many nodes (if ``dense_max_nodes`` >
#: 0). The decision's floor may factorize a dense n x n matrix up to the same size
#: (``lessmap.core.paper.drift.PROOF_MAX_NODES``), so its memory has one bound.
DENSE_STORE_MAX_NODES = 4096

#: Above ``dense_max_nodes`` nodes, a graph enters the dense store when at least this share
#: of its n(n-1)/2 pairs (in percent) are edges, and leaves it below ``DENSE_STAY_PERCENT``.
#: The dense store holds 24 B per pair against the sparse store's 24 B per edge, so it
#: holds at most 100/``DENSE_STAY_PERCENT`` times the sparse store's bytes per edge (times
#: its spare capacity, at most 1.27). The gap between the two keeps a graph near the
#: threshold from being converted back and forth.
DENSE_ENTER_PERCENT = 75
DENSE_STAY_PERCENT = 60

if TYPE_CHECKING:
    from collections.abc import Iterable

    from numpy.typing import NDArray
    from scipy import sparse

    from lessmap.core.paper.counts import BlockChanges, Changes, CountStore
    from lessmap.core.paper.spectral import Similarity


def _edge_share_at_least(edges: int, nodes: int, percent: int) -> bool:
    """Whether ``edges`` are at least ``percent`` % of the n(n-1)/2 pairs (exact integers)."""
    return 200 * edges >= percent * nodes * (nodes - 1)


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
        """Start an empty graph.

        Args:
            dense_max_nodes: hold the edges densely up to this many nodes (0: never).
        """
        self._dense_max = dense_max_nodes
        self._settled = 0  # nodes whose pairs were all counted: those before the frame
        self._index: dict[int, int] = {}
        self._ids = np.zeros(INITIAL_CAPACITY, dtype=np.int64)
        self._counts = np.zeros(INITIAL_CAPACITY, dtype=np.int64)
        self._first_seen = np.zeros(INITIAL_CAPACITY, dtype=np.int64)
        self._touched = np.zeros(INITIAL_CAPACITY, dtype=bool)
        self._size = 0
        self._store: CountStore
        self._fit_store(0, UpperCounts.empty())
        self._rates_stale = False

    # -- storage form ----------------------------------------------------------------------

    def _fit_store(
        self, nodes: int, upper: UpperCounts | None = None, *, counted: bool = False
    ) -> None:
        """Hold the edges in the store that suits the graph: the one place that picks it.

        The rule, on n nodes and e edges (``dense_max_nodes`` = 0: sparse always):

        - n <= ``dense_max_nodes``: dense (the solver gets a dense array);
        - n > ``DENSE_STORE_MAX_NODES``: sparse;
        - between: dense when e >= ``DENSE_ENTER_PERCENT`` % of n(n-1)/2, or when the dense
          store holds the graph already and e >= ``DENSE_STAY_PERCENT`` % (hysteresis).

        It is applied with ``upper`` (a state being loaded: entering, so the store follows
        from the state alone) and with ``counted`` (every pair of the frames so far is
        counted: at a frame's start, where only a dense store is checked, and before W is
        read). Otherwise the graph is growing by a node in the middle of a frame, whose
        pairs are not counted yet: a sparse store stays sparse, a dense one goes sparse past
        ``DENSE_STORE_MAX_NODES``, and a graph that crosses ``dense_max_nodes`` stays dense
        only when the graph at the frame's start was dense enough to enter. A new store
        starts without a mark.
        """
        held = upper is None and isinstance(self._store, DenseCounts)
        if upper is not None:
            dense = self._dense_enough(nodes, int(upper.counts.size), entering=True)
        elif counted:
            dense = self._dense_enough(nodes, self._store.edge_count(), entering=not held)
        elif not held:
            dense = False
        elif nodes <= self._dense_max:
            dense = True
        elif nodes > DENSE_STORE_MAX_NODES:
            dense = False
        elif nodes == self._dense_max + 1 and self._settled >= 2:
            dense = _edge_share_at_least(
                self._store.edge_count(), self._settled, DENSE_ENTER_PERCENT
            )
        else:
            dense = True
        if upper is None:
            if dense == held:
                self._store.resize(nodes)
                return
            upper = self._store.upper()
        limit = max(self._dense_max, DENSE_STORE_MAX_NODES)
        self._store = (
            DenseCounts(nodes, limit, upper, doubling_max=self._dense_max)
            if dense
            else SparseCounts(nodes, upper)
        )
        self._rates_stale = True  # a new store computes W in full at its first refresh

    def _dense_enough(self, nodes: int, edges: int, *, entering: bool) -> bool:
        """The store rule of ``_fit_store`` on n nodes and e edges."""
        if self._dense_max <= 0:
            return False
        if nodes <= self._dense_max:
            return True
        if nodes > DENSE_STORE_MAX_NODES:
            return False
        percent = DENSE_ENTER_PERCENT if entering else DENSE_STAY_PERCENT
        return _edge_share_at_least(edges, nodes, percent)

    # -- size ------------------------------------------------------------------------------

    @property
    def node_count(self) -> int:
        """Number of features (nodes)."""
        return self._size

    @property
    def is_dense(self) -> bool:
        """Whether the graph is in the dense small-graph form: W is handed over as an array.

        True exactly when the graph has at most ``dense_max_nodes`` nodes (> 0). A dense
        graph above that size may also be held in the dense store (``dense_store``), but its
        W is handed over as CSR, to the same solver as from the sparse store.
        """
        return self._size <= self._dense_max and isinstance(self._store, DenseCounts)

    @property
    def dense_store(self) -> bool:
        """Whether the edges are held in the dense store (``is_dense`` or a dense graph)."""
        return isinstance(self._store, DenseCounts)

    @property
    def edge_count(self) -> int:
        """Number of covisible pairs (undirected edges)."""
        return self._store.edge_count()

    @property
    def memory_edges(self) -> int:
        """Edges to charge the service's edge budgets with: what the graph costs in edges.

        The edge count, except for a dense graph held densely above ``dense_max_nodes``: the
        dense store holds every cell, edge or not, and a copy of W at a mark, so it is charged
        its bytes at the sparse store's 24 B per edge when that is more (up to ~3x its edges
        at the 60 % density where a graph leaves the dense store). Below ``dense_max_nodes``
        nothing changes: small graphs were always held densely and charged by their edges.
        """
        edges = self._store.edge_count()
        if isinstance(self._store, DenseCounts) and not self.is_dense:
            return max(edges, -(-self._store.held_bytes() // SPARSE_BYTES_PER_EDGE))
        return edges

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

    def add_frame(
        self, seq: int, features: Iterable[int], *, distinct: bool = False
    ) -> NDArray[np.int64]:
        """Count one frame: n_i += 1 per feature, a_ij += 1 per pair (§3.1).

        Duplicate IDs within a frame count once; an empty frame changes nothing.
        ``distinct=True`` promises a list of distinct Python ints in ascending order (the
        partitioner's), which skips the set; new features get their nodes in that order.

        Returns:
            The node indices of the frame's distinct features, sorted ascending.
        """
        self._settled = self._size
        if self._size > self._dense_max and isinstance(self._store, DenseCounts):
            # Between decisions (coalesced frames) too: a graph that thinned out leaves the
            # dense store at a frame's start, so its spare memory lasts one frame at most.
            self._fit_store(self._size, counted=True)
        if distinct and type(features) is list:
            nodes = self._intern_distinct(features, seq)
        else:
            nodes = self._intern(features, seq)
        if nodes.size == 0:
            return nodes
        self._counts[nodes] += 1
        self._touched[nodes] = True
        self._rates_stale = True
        self._store.add_frame(nodes)
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

    def _intern_distinct(self, features: list[int], seq: int) -> NDArray[np.int64]:
        # One C-level lookup pass; new features (rare once a room is known) one by one, in
        # the order ``_intern`` would create them (ascending IDs: the same node indices).
        nodes = list(map(self._index.get, features))
        if None in nodes:
            for at, node in enumerate(nodes):
                if node is None:
                    nodes[at] = self._new_node(features[at], seq)
        nodes.sort()  # no None is left
        return np.array(nodes, dtype=np.int64)

    def _new_node(self, feature: int, seq: int) -> int:
        self._fit_store(self._size + 1)
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

    def _refresh(self) -> None:
        """Bring W up to date for the nodes touched since it was last read."""
        if not self._rates_stale:
            return
        n = self._size
        if n > self._dense_max:
            self._fit_store(n, counted=True)  # every pair is counted: the store may change
        self._store.refresh(self._counts[:n], self._touched[:n])
        self._touched[:n] = False
        self._rates_stale = False

    # -- read ------------------------------------------------------------------------------

    def similarity(self) -> Similarity:
        """Return W (Eq. 1) in the form it is held: a dense read-only view or CSR.

        The spectral test takes either; the dense form spares small graphs the sparse
        containers, which cost more than the eigen-solve at tens of nodes.
        """
        self._refresh()
        if self.is_dense:
            return self._store.similarity_array()
        return self._store.similarity_csr()

    def degrees(self) -> NDArray[np.float64]:
        """Return the row sums d of W (Eq. 1), shape (n,), without building W's matrix."""
        self._refresh()
        return self._store.degrees()

    def mark(self) -> None:
        """Remember W as it stands now; ``changes`` reports what moved since."""
        self._refresh()
        self._store.mark()

    def changes(self) -> Changes | BlockChanges | None:
        """Return what of W moved since the last ``mark`` (None: no mark).

        The sparse form lists the changed entries (``Changes``), the dense form hands over
        the rows that may have moved (``BlockChanges``).

        A mark lasts until the graph is reshaped (``keep_only``, a load) or changes store
        (``_fit_store``); node indices never change in between, so the nodes added since
        the mark are the last ones.
        """
        self._refresh()
        return self._store.changes()

    def covrate_dense(self) -> NDArray[np.float64]:
        """Return W (Eq. 1) as a dense (n, n) array (a read-only view in the dense form)."""
        self._refresh()
        return self._store.similarity_array()

    def covrate(self) -> sparse.csr_array:
        """Return W (Eq. 1): symmetric CSR float64, shape (n, n), zero diagonal, in [0, 1]."""
        self._refresh()
        return self._store.similarity_csr()

    def edge_counts(self) -> sparse.csr_array:
        """Return a_ij as a symmetric CSR int64 matrix, shape (n, n)."""
        upper = self._store.upper().csr()
        symmetric: sparse.csr_array = (upper + upper.T).tocsr()
        return symmetric

    def pair_count(self, feature_a: int, feature_b: int) -> int:
        """Return a_ij for two feature IDs (0 when either is unknown or they never met)."""
        i, j = self._index.get(feature_a), self._index.get(feature_b)
        if i is None or j is None or i == j:
            return 0
        return self._store.pair_count(i, j)

    def count(self, feature: int) -> int:
        """Return n_i for a feature ID (0 when unknown)."""
        node = self._index.get(feature)
        return 0 if node is None else int(self._counts[node])

    # -- reshape ---------------------------------------------------------------------------

    def keep_only(self, nodes: NDArray[np.int64]) -> None:
        """Drop every node not in ``nodes`` with its edges; keep counts among the rest.

        Node indices are renumbered in their old order, so the result is deterministic.
        """
        keep = np.zeros(self._size, dtype=bool)
        keep[nodes] = True
        kept = np.flatnonzero(keep)
        upper = self._store.upper(kept)
        state = CovGraphState(
            feature_ids=self._ids[kept].copy(),
            counts=self._counts[kept].copy(),
            first_seen=self._first_seen[kept].copy(),
            edge_indptr=upper.indptr,
            edge_indices=upper.indices,
            edge_counts=upper.counts,
        )
        self._load(state)

    # -- snapshot --------------------------------------------------------------------------

    def state(self) -> CovGraphState:
        """Return a copy of the whole graph as arrays (always the CSR form)."""
        n = self._size
        upper = self._store.upper()
        return CovGraphState(
            feature_ids=self._ids[:n].copy(),
            counts=self._counts[:n].copy(),
            first_seen=self._first_seen[:n].copy(),
            edge_indptr=upper.indptr,
            edge_indices=upper.indices,
            edge_counts=upper.counts,
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
        capacity = max(INITIAL_CAPACITY, n)
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
        upper = UpperCounts(
            np.asarray(state.edge_indptr, dtype=np.int64),
            np.asarray(state.edge_indices, dtype=np.int64),
            np.asarray(state.edge_counts, dtype=np.int64),
        )
        self._fit_store(n, upper)
        self._rates_stale = True  # recomputed in full: same formula, same values

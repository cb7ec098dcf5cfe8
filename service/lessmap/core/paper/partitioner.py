"""The partitioner of one robot session: frames in, transitions out (LESS-mapping §3).

Rules of this file:

1. Frames are applied in strictly increasing seq; anything else is a ``StaleFrameError``
   and changes nothing, so a caller can retry or drop without corrupting the session.
2. ``apply`` only counts; ``decide`` runs the spectral test once for the frames applied since
   the last decision (``observe`` = both: a loaded service coalesces, never drops).
3. After a transition, the cluster that holds most of the last frame's features is the new
   area (ties: the cluster whose features were first seen later). The other side is closed
   as a submap. The new CovGraph keeps the new cluster (``seed``) or starts empty (``fresh``).
4. Everything that influences a later decision is in ``PartitionerState``; a restored
   partitioner makes exactly the decisions the original would have made. The λ2 floor
   (``drift``) is not state: a restored one proves afresh and decides the same.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from lessmap.core.errors import GraphError, StaleFrameError
from lessmap.core.paper.covgraph import CovGraph, CovGraphState
from lessmap.core.paper.drift import Prover
from lessmap.core.paper.params import PartitionParams, SeedMode
from lessmap.core.paper.spectral import Bisection, Components, cut_endpoints, split_graph
from lessmap.core.paper.submaps import Evaluation, Reason, Submap, Transition

if TYPE_CHECKING:
    from collections.abc import Iterable

    from numpy.typing import NDArray


class FrameRecord(NamedTuple):
    """A frame kept for the boundary estimate: its seq and distinct feature IDs.

    A tuple of an int and an array, which the cyclic collector stops tracking: a fleet's
    histories hold hundreds of thousands of them, and every full collection walked them all.
    """

    seq: int
    features: NDArray[np.int64]


@dataclass(frozen=True, slots=True, kw_only=True)
class PartitionerState:
    """The whole state of a partitioner, for snapshots (see ``lessmap.core.paper.snapshot``)."""

    params: PartitionParams
    graph: CovGraphState
    history: tuple[FrameRecord, ...]
    closed_submaps: tuple[Submap, ...]
    submap_id: int
    submap_first_seq: int | None
    submap_frame_count: int
    last_seq: int | None
    last_stamp_s: float
    last_features: tuple[int, ...]  # distinct features of the last non-empty frame
    pending_frames: int  # applied since the last decision
    pending_nonempty: bool
    frames_since_transition: int
    frames_applied: int
    transitions: int


@dataclass(slots=True, kw_only=True)  # not frozen: built at every decision, internal
class Decision:
    """Everything one spectral test found (Eq. 4), before the partitioner acts on it.

    ``Partitioner.decide`` computes one per test; the ``Evaluation`` it reports and the
    ``Transition`` it declares are both derived from it, each in one place.
    """

    seq: int  # the last frame the test covers
    nodes: int  # CovGraph size
    components: int = 1  # > 1 when the CovGraph fell apart
    ncut: float | None = None  # of the bisection, when one was computed and counts
    lambda2: float | None = None
    lambda2_above: float | None = None  # settled by proving λ2 > this (λ2_min), no solve
    reason: Reason | None = None  # a split was found: a bisection passing Eq. 4, or components
    new_side: NDArray[np.bool_] | None = None  # with a reason: the nodes of the new area
    boundary: NDArray[np.integer] | None = None  # with a transition: ends of cut edges
    transition: bool = False  # a split was found and it passes the min_cluster_size guard

    def evaluation(self) -> Evaluation:
        """The figures reported for this decision (``Partitioner.last_evaluation``)."""
        return Evaluation(
            seq=self.seq,
            nodes=self.nodes,
            components=self.components,
            ncut=self.ncut,
            lambda2=self.lambda2,
            transition=self.transition,
            lambda2_above=self.lambda2_above,
        )


_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
_INT_ONLY = frozenset({int})  # not bool: True is refused as a feature ID


def _plain_ids(features: Iterable[int]) -> list[int] | None:
    """The distinct IDs of a list of Python ints in the int64 range, sorted; else None.

    A decoded frame's features come this way (every frame of a fleet): set and sort them
    in Python, half the cost of numpy's conversion for a frame of ~20. Anything else (bools,
    floats, IDs beyond int64, arrays) is None, left to ``_numpy_ids`` and its messages.
    """
    # ``map(type, …)`` checks the types in C, a generator in Python: this runs every frame.
    if type(features) is list and set(map(type, features)) <= _INT_ONLY:
        ids = sorted(set(features))
        if not ids or (ids[0] >= _INT64_MIN and ids[-1] <= _INT64_MAX):
            return ids
    return None


def _feature_ids(seq: int, features: Iterable[int]) -> tuple[list[int], NDArray[np.int64]]:
    """The distinct feature IDs, ascending, as Python ints and as int64 (both are needed).

    Raises:
        GraphError: an ID is not an integer in the int64 range (floats, strings, bools).
    """
    ids = _plain_ids(features)
    if ids is not None:
        return ids, np.array(ids, dtype=np.int64)
    distinct = _numpy_ids(seq, features)
    return distinct.tolist(), distinct


def _feature_id_list(seq: int, features: Iterable[int]) -> list[int]:
    """The distinct feature IDs, ascending, as Python ints: ``_feature_ids`` without the array.

    Raises:
        GraphError: as ``_feature_ids``.
    """
    ids = _plain_ids(features)
    return ids if ids is not None else _numpy_ids(seq, features).tolist()


def _numpy_ids(seq: int, features: Iterable[int]) -> NDArray[np.int64]:
    """Return the distinct feature IDs as int64, refusing floats, strings and bools."""
    values = features if isinstance(features, np.ndarray) else list(features)
    try:
        array = np.asarray(values)
    except (OverflowError, TypeError, ValueError) as exc:
        msg = f"frame {seq}: feature IDs must be integers in the int64 range ({exc})"
        raise GraphError(msg) from exc
    if array.size == 0:
        return np.zeros(0, dtype=np.int64)
    # numpy casts 1.5, "7" and True to int64 without complaint; only integer dtypes pass.
    # Python ints beyond int64 give an object array, which fails here too.
    if array.ndim != 1 or array.dtype.kind not in "iu":
        msg = f"frame {seq}: feature IDs must be integers in the int64 range, got {array.dtype}"
        raise GraphError(msg)
    if array.dtype.kind == "u" and array.max() > np.iinfo(np.int64).max:
        msg = f"frame {seq}: feature ID {array.max()} is beyond the int64 range"
        raise GraphError(msg)
    # np.unique, without its layers of Python: one sort, then drop repeats if there are any.
    distinct = np.sort(array.astype(np.int64, copy=False))
    if distinct.size > 1:
        new = distinct[1:] != distinct[:-1]
        if not new.all():
            distinct = distinct[np.concatenate(([True], new))]
    return distinct


class Partitioner:
    """CovGraph and submap state of one robot session. No I/O."""

    def __init__(
        self, params: PartitionParams | None = None, *, always_solve: bool = False
    ) -> None:
        """Start an empty session.

        Args:
            params: thresholds and guards (the laser profile by default).
            always_solve: run the eigen-solve at every decision, for tools that plot Ncut
                and λ2 over time. By default a decision that provably cannot pass Eq. 4
                (λ2 > λ2_min, ``lambda2_exceeds``) skips it; the decisions are the same,
                only ``last_evaluation`` then holds no Ncut and λ2 for it.
        """
        self.params = params if params is not None else PartitionParams()
        self.always_solve = always_solve
        self._graph = CovGraph(self.params.dense_max_nodes)
        self._history: deque[FrameRecord] = deque(maxlen=self.params.history_frames)
        self._closed: deque[Submap] = deque(maxlen=self.params.keep_closed_submaps)
        self._submap_id = 0
        self._submap_first_seq: int | None = None
        self._submap_frame_count = 0
        self._last_seq: int | None = None
        self._last_stamp_s = 0.0
        self._last_features: tuple[int, ...] = ()
        self._pending_frames = 0
        self._pending_nonempty = False
        self._frames_since_transition = 0
        self._frames_applied = 0
        self._transitions = 0
        self._prover = Prover()
        self._last_decision: Decision | None = None
        self._last_evaluation: Evaluation | None = None

    # -- read ------------------------------------------------------------------------------

    @property
    def last_evaluation(self) -> Evaluation | None:
        """The figures of the last decision that ran the test (None before the first).

        Made when first read: a session decides at every frame and is rarely asked.
        """
        if self._last_evaluation is None and self._last_decision is not None:
            self._last_evaluation = self._last_decision.evaluation()
        return self._last_evaluation

    @property
    def graph(self) -> CovGraph:
        """The current submap's CovGraph (read it, don't change it)."""
        return self._graph

    @property
    def last_seq(self) -> int | None:
        """Seq of the last applied frame, None before the first."""
        return self._last_seq

    @property
    def oldest_boundary_seq(self) -> int | None:
        """The earliest frame a transition's boundary can still fall on (its kept history).

        ``_boundary_seq`` walks back over the kept frames only, so a caller that maps
        boundaries (``areas``' pools) can forget whatever lies before this one.
        """
        return self._history[0].seq if self._history else None

    @property
    def frames_applied(self) -> int:
        """Frames applied since the session began."""
        return self._frames_applied

    @property
    def transitions(self) -> int:
        """Transitions declared since the session began."""
        return self._transitions

    @property
    def pending_frames(self) -> int:
        """Frames applied but not yet covered by a decision."""
        return self._pending_frames

    @property
    def closed_submaps(self) -> tuple[Submap, ...]:
        """Closed submaps, oldest first (at most ``params.keep_closed_submaps``)."""
        return tuple(self._closed)

    def current_submap(self) -> Submap:
        """The open submap: its features so far and its frames."""
        first = self._submap_first_seq
        last = self._last_seq
        return Submap(
            id=self._submap_id,
            first_seq=first if first is not None else 0,
            last_seq=last if last is not None else 0,
            frame_count=self._submap_frame_count,
            features=tuple(sorted(self._graph.feature_ids.tolist())),
        )

    # -- frames ----------------------------------------------------------------------------

    def observe(self, seq: int, stamp_s: float, features: Iterable[int]) -> Transition | None:
        """Add one frame and decide at once; return the transition it reveals, if any."""
        self.apply(seq, stamp_s, features)
        return self.decide()

    def apply(self, seq: int, stamp_s: float, features: Iterable[int]) -> None:
        """Count one frame into the CovGraph without running the spectral test.

        Raises:
            StaleFrameError: seq is not greater than the last applied seq.
            GraphError: a feature ID is not an integer in the int64 range.
        """
        if self._last_seq is not None and seq <= self._last_seq:
            msg = f"frame seq {seq} is not after the last applied seq {self._last_seq}"
            raise StaleFrameError(msg)
        ids, distinct = _feature_ids(seq, features)
        self._count(seq, stamp_s, ids, distinct)

    def apply_distinct(self, seq: int, stamp_s: float, ids: list[int]) -> None:
        """``apply`` for IDs that are distinct Python ints in ascending order already.

        The areas tracker hands its pools this way: checking them again cost as much as
        counting a small frame.

        Raises:
            StaleFrameError: seq is not greater than the last applied seq.
            GraphError: an ID is outside the int64 range (``apply``'s check and message).
        """
        if self._last_seq is not None and seq <= self._last_seq:
            msg = f"frame seq {seq} is not after the last applied seq {self._last_seq}"
            raise StaleFrameError(msg)
        try:
            distinct = np.array(ids, dtype=np.int64)
        except OverflowError:
            ids, distinct = _feature_ids(seq, ids)  # raises apply's error for the ID
        self._count(seq, stamp_s, ids, distinct)

    def _count(self, seq: int, stamp_s: float, ids: list[int], distinct: NDArray[np.int64]) -> None:
        self._graph.add_frame(seq, ids, distinct=True)
        self._history.append(FrameRecord(seq, distinct))
        if self._submap_first_seq is None:
            self._submap_first_seq = seq
        self._submap_frame_count += 1
        self._last_seq = seq
        self._last_stamp_s = float(stamp_s)
        self._pending_frames += 1
        self._frames_since_transition += 1
        self._frames_applied += 1
        if ids:
            self._last_features = tuple(ids)
            self._pending_nonempty = True

    def decide(self) -> Transition | None:
        """Run the spectral test once for every frame applied since the last decision."""
        if self._pending_frames == 0:
            return None
        batch_frames = self._pending_frames
        self._pending_frames = 0
        if not self._pending_nonempty:
            return None  # empty frames change nothing, so the last decision stands
        self._pending_nonempty = False
        if self._frames_since_transition <= self.params.min_frames_between:
            return None
        assert self._last_seq is not None  # a pending frame was applied
        decision = self._test(self._last_seq)
        self._last_decision, self._last_evaluation = decision, None
        if not decision.transition:
            return None
        return self._transition(decision, batch_frames)

    def _test(self, seq: int) -> Decision:
        """Run the spectral test (Eq. 4) on the CovGraph as it stands; change nothing."""
        nodes = self._graph.node_count
        if nodes < 2:
            return Decision(seq=seq, nodes=nodes)
        bound = self.params.lambda2_min
        # Proven λ2 > λ2_min settles the decision without W's matrix or a solve.
        if not self.always_solve and self._prover.certify(self._graph, bound):
            return Decision(seq=seq, nodes=nodes, lambda2_above=bound)
        # W in the form the graph holds it: dense arrays when small, CSR when large.
        w = self._graph.similarity()
        split = split_graph(w, dense_max_nodes=self.params.dense_max_nodes)
        if isinstance(split, Bisection) and split.lambda2 > bound and not self.always_solve:
            self._prover.solved(self._graph, w, split.lambda2, bound)  # renew the floor
        if isinstance(split, Components):
            reason, components = Reason.DISCONNECTED, split.count
            ncut = lambda2 = None
            new_side = self._new_component(split.labels)
        elif split.ncut <= self.params.ncut_min and split.lambda2 <= self.params.lambda2_min:
            reason, components = Reason.SPECTRAL, 1
            ncut, lambda2 = split.ncut, split.lambda2
            new_side = self._new_cluster(split.labels)
        else:
            return Decision(seq=seq, nodes=nodes, ncut=split.ncut, lambda2=split.lambda2)
        small = min(int(new_side.sum()), int((~new_side).sum()))
        transition = small >= self.params.min_cluster_size
        return Decision(
            seq=seq,
            nodes=nodes,
            components=components,
            ncut=ncut,
            lambda2=lambda2,
            reason=reason,
            new_side=new_side,
            boundary=cut_endpoints(w, new_side) if transition else None,
            transition=transition,
        )

    # -- deciding which side is new ---------------------------------------------------------

    def _current_nodes(self) -> NDArray[np.int64]:
        return self._graph.nodes_of(self._last_features)

    def _new_cluster(self, labels: NDArray[np.int8]) -> NDArray[np.bool_]:
        """Mask of the side that holds most of the last frame (rule 3)."""
        side = labels.astype(bool)
        current = self._current_nodes()
        on_side = int(side[current].sum())
        off_side = current.size - on_side
        if on_side != off_side:
            return side if on_side > off_side else ~side
        first_seen = self._graph.first_seen
        newer = first_seen[side].mean() > first_seen[~side].mean()
        return side if newer else ~side

    def _new_component(self, component_of: NDArray[np.int32]) -> NDArray[np.bool_]:
        """Mask of the component that holds most of the last frame; the rest are closed."""
        current = self._current_nodes()
        votes = np.bincount(component_of[current], minlength=int(component_of.max()) + 1)
        best = np.flatnonzero(votes == votes.max())
        if best.size > 1:
            first_seen = self._graph.first_seen
            newest = [first_seen[component_of == c].mean() for c in best]
            best = best[[int(np.argmax(newest))]]
        mask: NDArray[np.bool_] = component_of == best[0]
        return mask

    # -- transition ------------------------------------------------------------------------

    def _transition(self, decision: Decision, batch_frames: int) -> Transition:
        """Close the old area, open the new one and return the transition (state changes)."""
        assert decision.reason is not None
        assert decision.new_side is not None
        assert decision.boundary is not None
        seq, new_side = decision.seq, decision.new_side
        ids = self._graph.feature_ids
        new_ids = np.sort(ids[new_side])
        old_ids = np.sort(ids[~new_side])
        boundary = np.unique(ids[decision.boundary])

        boundary_seq = self._boundary_seq(new_ids)
        opened_frames = sum(1 for record in self._history if record.seq >= boundary_seq)
        first_seq = self._submap_first_seq if self._submap_first_seq is not None else seq
        closed = Submap(
            id=self._submap_id,
            first_seq=first_seq,
            last_seq=max(first_seq, boundary_seq - 1),
            frame_count=self._submap_frame_count - opened_frames,
            features=tuple(old_ids.tolist()),
        )
        opened = Submap(
            id=self._submap_id + 1,
            first_seq=boundary_seq,
            last_seq=seq,
            frame_count=opened_frames,
            features=tuple(new_ids.tolist()),
        )
        transition = Transition(
            seq=seq,
            boundary_seq=boundary_seq,
            stamp_s=self._last_stamp_s,
            reason=decision.reason,
            ncut=decision.ncut,
            lambda2=decision.lambda2,
            closed=closed,
            opened=opened,
            boundary_features=tuple(boundary.tolist()),
            batch_frames=batch_frames,
        )
        self._closed.append(closed)
        self._open_next(new_side, opened)
        return transition

    def _boundary_seq(self, new_ids: NDArray[np.int64]) -> int:
        """Estimate the first frame in the new area.

        Walking back from the detection frame, the boundary is the first frame of the
        trailing run of frames whose features lie mostly (> half) in the new cluster; empty
        frames neither break nor start the run. The closed submap keeps at least its first
        frame, so the boundary is never the submap's first frame when it has several.
        """
        records = list(self._history)
        new_set = set(new_ids.tolist())  # set look-ups: cheaper than np.isin on short frames
        start = len(records) - 1
        for index in range(len(records) - 1, -1, -1):
            features = records[index].features.tolist()
            if not features:
                continue
            inside = sum(1 for feature in features if feature in new_set)
            if 2 * inside <= len(features):
                break
            start = index
        if start == 0 and len(records) > 1 and records[0].seq == self._submap_first_seq:
            start = 1
        return records[start].seq

    def _open_next(self, new_side: NDArray[np.bool_], opened: Submap) -> None:
        self._prover.reset()
        if self.params.seed_mode is SeedMode.SEED:
            self._graph.keep_only(np.flatnonzero(new_side))
        else:
            self._graph = CovGraph(self.params.dense_max_nodes)
        kept = [record for record in self._history if record.seq >= opened.first_seq]
        self._history.clear()
        self._history.extend(kept)
        self._submap_id = opened.id
        self._submap_first_seq = opened.first_seq
        self._submap_frame_count = opened.frame_count
        self._frames_since_transition = 0
        self._transitions += 1

    # -- snapshot --------------------------------------------------------------------------

    def state(self) -> PartitionerState:
        """Return the whole state (arrays copied), enough to continue exactly."""
        return PartitionerState(
            params=self.params,
            graph=self._graph.state(),
            history=tuple(self._history),
            closed_submaps=tuple(self._closed),
            submap_id=self._submap_id,
            submap_first_seq=self._submap_first_seq,
            submap_frame_count=self._submap_frame_count,
            last_seq=self._last_seq,
            last_stamp_s=self._last_stamp_s,
            last_features=self._last_features,
            pending_frames=self._pending_frames,
            pending_nonempty=self._pending_nonempty,
            frames_since_transition=self._frames_since_transition,
            frames_applied=self._frames_applied,
            transitions=self._transitions,
        )

    @classmethod
    def from_state(cls, state: PartitionerState, *, always_solve: bool = False) -> Partitioner:
        """Rebuild a partitioner that makes exactly the decisions the original would."""
        partitioner = cls(state.params, always_solve=always_solve)
        partitioner._graph = CovGraph.from_state(state.graph, state.params.dense_max_nodes)
        partitioner._history.extend(state.history)
        partitioner._closed.extend(state.closed_submaps)
        partitioner._submap_id = state.submap_id
        partitioner._submap_first_seq = state.submap_first_seq
        partitioner._submap_frame_count = state.submap_frame_count
        partitioner._last_seq = state.last_seq
        partitioner._last_stamp_s = state.last_stamp_s
        partitioner._last_features = state.last_features
        partitioner._pending_frames = state.pending_frames
        partitioner._pending_nonempty = state.pending_nonempty
        partitioner._frames_since_transition = state.frames_since_transition
        partitioner._frames_applied = state.frames_applied
        partitioner._transitions = state.transitions
        return partitioner

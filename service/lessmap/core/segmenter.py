"""One interface over the segmentation methods, so that a service can run either per session.

``Segmenter``: frames in (``apply``), changes out (``decide``), its segments, area graph and
bytes. ``PaperSegmenter`` wraps a ``Partitioner``, ``AreasSegmenter`` an ``AreaTracker`` and
its ``AreaGraphBuilder``. No I/O. Rules (in full: ``docs/design/segmenter.md``):

1. The wrapped method decides: an adapter adds no rule of its own.
2. Errors at apply, before any change: the partitioner's checks, for every method.
3. Changes wait for ``decide`` (oldest first); segments and graph already include them.
4. A change closes a segment (ids 0, 1, 2, ...) and enters an area; under the paper every
   segment is its own area, under areas segments of one area recur (``revisit_of``).
5. Bounded: what an adapter keeps grows with changes, never frames, and is cut.
6. Whole state in bytes: ``segmenter_from_bytes`` goes on exactly as the original.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final, Protocol

from lessmap.core import segmenter_snapshot as record
from lessmap.core.areas import snapshot as areas_snapshot
from lessmap.core.areas.graph import (
    MAX_BOUNDARY_FEATURES,
    AreaEdge,
    AreaGraph,
    AreaGraphBuilder,
    AreaNode,
)
from lessmap.core.areas.tracker import AreaParams, AreaTracker
from lessmap.core.closed_segments import ClosedSegments
from lessmap.core.errors import GraphError, StaleFrameError
from lessmap.core.paper import snapshot
from lessmap.core.paper.params import PartitionParams
from lessmap.core.paper.partitioner import Partitioner, _feature_id_list  # rule 2: its check
from lessmap.core.paper.submaps import Submap
from lessmap.core.rooms.params import RoomParams
from lessmap.core.rooms.tracker import RoomTracker
from lessmap.core.segment_change import (
    SIGHTING_EDGES,
    Method,
    SegmentChange,
    change_from,
    pack_beside,
    unpack_beside,
)
from lessmap.core.segmenter_rooms import RoomsSegmenter

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence


__all__ = [
    "DEFAULT_METHOD",
    "SIGHTING_EDGES",
    "AreasSegmenter",
    "Method",
    "PaperSegmenter",
    "RoomsSegmenter",
    "SegmentChange",
    "Segmenter",
    "make_segmenter",
    "segmenter_from_bytes",
]


#: The method of a new session and of the offline commands unless one is chosen: ``areas``
#: met its targets (``docs/decisions/0002-areas-by-default.md``); ``--method paper`` remains.
DEFAULT_METHOD: Final = Method.AREAS


class Segmenter(Protocol):
    """What a robot session drives, whichever the method (rules 1-6)."""

    @property
    def method(self) -> Method:
        """The method that decides."""

    @property
    def last_seq(self) -> int | None:
        """Seq of the last applied frame, None before the first."""

    @property
    def frames_applied(self) -> int:
        """Frames applied since the session began."""

    @property
    def transitions(self) -> int:
        """Changes found since the session began (held ones included, rule 3)."""

    @property
    def pending_frames(self) -> int:
        """Frames applied since the last ``decide``."""

    @property
    def current_area(self) -> int:
        """The area of the open segment."""

    @property
    def node_count(self) -> int:
        """Nodes of the CovGraph that bounds the session's memory."""

    @property
    def edge_count(self) -> int:
        """Edges of that CovGraph."""

    @property
    def memory_edges(self) -> int:
        """What that CovGraph costs in edges, for the edge budgets (``CovGraph.memory_edges``)."""

    @property
    def max_features_kept(self) -> int:
        """Features of one frame that reach the CovGraph at most (0: all), for the budgets."""

    @property
    def closed_submaps(self) -> Sequence[Submap]:
        """Closed segments, oldest first (rule 5)."""

    def feature_known(self, feature: int) -> bool:
        """Whether a feature is a node of that CovGraph."""

    def apply(self, seq: int, stamp_s: float, features: Iterable[int]) -> None:
        """Take one frame (rule 2).

        Raises:
            StaleFrameError: seq is not greater than the last applied seq.
            GraphError: a feature ID is not an integer in the int64 range.
        """

    def decide(self) -> tuple[SegmentChange, ...]:
        """The changes found since the last ``decide``, oldest first (rules 1, 3)."""

    def current_submap(self) -> Submap:
        """The open segment."""

    def area_graph(self) -> AreaGraph:
        """This robot's areas and passages so far."""

    def to_bytes(self) -> bytes:
        """The whole state (rule 6)."""


def make_segmenter(
    method: Method | str,
    params: PartitionParams | None = None,
    area_params: AreaParams | None = None,
    room_params: RoomParams | None = None,
) -> Segmenter:
    """A new session's segmenter; each method reads its own parameters, not the other's.

    Raises:
        GraphError: the method is not one of ``Method``.
    """
    try:
        chosen = Method(method)
    except ValueError:
        msg = f"unknown segmentation method {method!r}; choose one of {', '.join(Method)}"
        raise GraphError(msg) from None
    if chosen is Method.PAPER:
        return PaperSegmenter(Partitioner(params))
    if chosen is Method.ROOMS:
        return RoomsSegmenter(RoomTracker(room_params))
    return AreasSegmenter(AreaTracker(area_params))


def segmenter_from_bytes(data: bytes) -> Segmenter:
    """Rebuild a segmenter from ``to_bytes``, or a paper one from a partitioner snapshot.

    Raises:
        GraphError: the bytes are neither, or are damaged.
    """
    if not record.is_record(data):
        if not data.startswith((b"LMSNAP", b"PK")):  # the partitioner snapshot's two forms
            msg = f"not a segmenter or partitioner snapshot (starts {bytes(data[:8])!r})"
            raise GraphError(msg)
        return PaperSegmenter(snapshot.from_bytes(data))
    found = record.unpack(data)
    try:
        if found.method == Method.PAPER:
            return PaperSegmenter._from_record(found)
        if found.method == Method.AREAS:
            return AreasSegmenter._from_record(found)
        if found.method == Method.ROOMS:
            return RoomsSegmenter.from_record(found)
    except GraphError:
        raise
    except Exception as exc:  # a well-framed record with a malformed part: one error type
        msg = f"not a segmenter snapshot: {type(exc).__name__}: {exc}"
        raise GraphError(msg) from exc
    msg = f"segmenter snapshot of unknown method {found.method!r}"
    raise GraphError(msg)


class PaperSegmenter:
    """The paper's ``Partitioner`` as a ``Segmenter``."""

    method: Final = Method.PAPER

    def __init__(
        self,
        partitioner: Partitioner | None = None,
        boundaries: Mapping[int, tuple[int, ...]] | None = None,
    ) -> None:
        """Wrap a partitioner; ``boundaries`` are its closed segments' boundary features."""
        self.partitioner = partitioner if partitioner is not None else Partitioner()
        # closed segment id -> the boundary features of the transition that closed it
        self._boundaries: dict[int, tuple[int, ...]] = dict(boundaries or {})

    @property
    def last_seq(self) -> int | None:
        """Seq of the last applied frame."""
        return self.partitioner.last_seq

    @property
    def frames_applied(self) -> int:
        """Frames applied."""
        return self.partitioner.frames_applied

    @property
    def transitions(self) -> int:
        """Transitions declared."""
        return self.partitioner.transitions

    @property
    def pending_frames(self) -> int:
        """Frames applied since the last ``decide``."""
        return self.partitioner.pending_frames

    @property
    def current_area(self) -> int:
        """The open segment's id: one more per transition, from 0."""
        return self.partitioner.transitions

    @property
    def node_count(self) -> int:
        """Nodes of the partitioner's CovGraph."""
        return self.partitioner.graph.node_count

    @property
    def edge_count(self) -> int:
        """Edges of the partitioner's CovGraph."""
        return self.partitioner.graph.edge_count

    @property
    def memory_edges(self) -> int:
        """What the partitioner's CovGraph costs in edges (``CovGraph.memory_edges``)."""
        return self.partitioner.graph.memory_edges

    @property
    def max_features_kept(self) -> int:
        """0: the paper keeps every feature."""
        return 0

    @property
    def closed_submaps(self) -> tuple[Submap, ...]:
        """The partitioner's closed submaps."""
        return self.partitioner.closed_submaps

    def feature_known(self, feature: int) -> bool:
        """Whether a feature is a node of the partitioner's CovGraph."""
        return self.partitioner.graph.count(feature) > 0

    def apply(self, seq: int, stamp_s: float, features: Iterable[int]) -> None:
        """``Partitioner.apply``."""
        self.partitioner.apply(seq, stamp_s, features)

    def decide(self) -> tuple[SegmentChange, ...]:
        """``Partitioner.decide``: no change or one."""
        transition = self.partitioner.decide()
        if transition is None:
            return ()
        closed = transition.closed.id
        # ascending ids with a count of 1 each: the ones an area graph would keep (rule 5)
        self._boundaries[closed] = transition.boundary_features[:MAX_BOUNDARY_FEATURES]
        while len(self._boundaries) > self.partitioner.params.keep_closed_submaps:
            del self._boundaries[next(iter(self._boundaries))]
        change = SegmentChange(
            transition=transition,
            reason=transition.reason.value,
            area=transition.opened.id,
            left_area=closed,
            revisit_of=None,
        )
        return (change,)

    def current_submap(self) -> Submap:
        """The open submap."""
        return self.partitioner.current_submap()

    def area_graph(self) -> AreaGraph:
        """Each remembered segment an area, each transition between two a passage (rule 4)."""
        closed = self.partitioner.closed_submaps
        current = self.partitioner.current_submap()
        segments = [*closed, current] if current.frame_count else list(closed)
        nodes = tuple(
            AreaNode(
                area=s.id,
                frames=s.frame_count,
                visits=1,
                first_seq=s.first_seq,
                last_seq=s.last_seq,
                features=s.features,
            )
            for s in segments
        )
        edges = tuple(
            AreaEdge(
                a=s.id,
                b=s.id + 1,
                a_to_b=1,
                b_to_a=0,
                boundary_features=tuple((f, 1) for f in self._boundaries.get(s.id, ())),
            )
            for s in closed
        )
        return AreaGraph(nodes=nodes, edges=edges)

    def to_bytes(self) -> bytes:
        """The partitioner's snapshot and the boundary features (rule 6)."""
        meta = {"boundaries": [[i, list(f)] for i, f in self._boundaries.items()]}
        return record.pack(Method.PAPER, meta, snapshot.to_bytes(self.partitioner), {})

    @classmethod
    def _from_record(cls, found: record.Record) -> PaperSegmenter:
        boundaries = {int(i): tuple(f) for i, f in found.meta["boundaries"]}
        return cls(snapshot.from_bytes(found.inner), boundaries)


class AreasSegmenter:
    """An ``AreaTracker`` and its ``AreaGraphBuilder`` as a ``Segmenter``."""

    method: Final = Method.AREAS

    def __init__(
        self,
        tracker: AreaTracker | None = None,
        builder: AreaGraphBuilder | None = None,
        *,
        closed: Iterable[Submap] = (),
        held: Iterable[SegmentChange] = (),
        pending_frames: int = 0,
    ) -> None:
        """Wrap a tracker and the builder fed its changes so far (new ones by default)."""
        self.tracker = tracker if tracker is not None else AreaTracker()
        self.builder = builder if builder is not None else AreaGraphBuilder()
        bound = PartitionParams().keep_closed_submaps  # the proposer keeps none (AreaParams)
        self._closed = ClosedSegments(bound, closed)
        self._held: list[SegmentChange] = list(held)  # found, not yet decided (rule 3)
        self._pending_frames = pending_frames

    @property
    def last_seq(self) -> int | None:
        """Seq of the last applied frame."""
        return self.tracker.last_seq

    @property
    def frames_applied(self) -> int:
        """Frames applied."""
        return self.tracker.frames_applied

    @property
    def transitions(self) -> int:
        """Changes the tracker found, held ones included."""
        return self.tracker.transitions

    @property
    def pending_frames(self) -> int:
        """Frames applied since the last ``decide``."""
        return self._pending_frames

    @property
    def current_area(self) -> int:
        """The tracker's current area."""
        return self.tracker.current

    @property
    def node_count(self) -> int:
        """Nodes of the proposer's CovGraph (its frames are pools of frames)."""
        return self.tracker.proposer.graph.node_count

    @property
    def edge_count(self) -> int:
        """Edges of the proposer's CovGraph."""
        return self.tracker.proposer.graph.edge_count

    @property
    def memory_edges(self) -> int:
        """What the proposer's CovGraph and the area models cost in edges.

        The graph's ``CovGraph.memory_edges``, plus ``SIGHTING_EDGES`` per sighting the area
        models hold (rule 9 bounds them), so the service's edge budgets see an areas
        session's memory, not only its graph's.
        """
        return self.tracker.proposer.graph.memory_edges + SIGHTING_EDGES * self.tracker.sightings

    @property
    def max_features_kept(self) -> int:
        """The tracker's ``AreaParams.max_features_kept`` (0: all)."""
        return self.tracker.params.max_features_kept

    @property
    def closed_submaps(self) -> tuple[Submap, ...]:
        """The segments closed by the changes found, oldest first."""
        return tuple(self._closed)

    def feature_known(self, feature: int) -> bool:
        """Whether a feature is a node of the proposer's CovGraph (the open pool's are not)."""
        return self.tracker.proposer.graph.count(feature) > 0

    def apply(self, seq: int, stamp_s: float, features: Iterable[int]) -> None:
        """Count one frame in; its tests wait for ``decide`` (rule 2)."""
        last = self.tracker.last_seq
        if last is not None and seq <= last:
            msg = f"frame seq {seq} is not after the last applied seq {last}"
            raise StaleFrameError(msg)
        self.tracker.add(seq, float(stamp_s), _feature_id_list(seq, features))
        self._pending_frames += 1

    def decide(self) -> tuple[SegmentChange, ...]:
        """Settle the frames applied since the last ``decide``; the changes held, oldest first.

        Once for several frames under load (the service's coalescing): the area tests run
        once, at the last frame, as the paper's test does.
        """
        if self._pending_frames:
            found = self.tracker.settle()
            if found is not None:
                self.builder.add(found)
                self._closed.append(found.transition.closed)
                self._held.append(change_from(found))
        changes = tuple(self._held)
        self._held.clear()
        self._pending_frames = 0
        return changes

    def current_submap(self) -> Submap:
        """The tracker's open segment."""
        return self.tracker.current_segment()

    def area_graph(self) -> AreaGraph:
        """The builder's graph, the open segment included and merges resolved."""
        return self.builder.graph(self.tracker)

    def to_bytes(self) -> bytes:
        """The tracker's snapshot, the builder's sums, the segments and held changes."""
        inner = areas_snapshot.to_bytes(self.tracker)
        return pack_beside(
            Method.AREAS, inner, self.builder, self._closed, self._held, self._pending_frames
        )

    @classmethod
    def _from_record(cls, found: record.Record) -> AreasSegmenter:
        builder, closed, held, pending = unpack_beside(found)
        return cls(
            areas_snapshot.from_bytes(found.inner),
            builder,
            closed=closed,
            held=held,
            pending_frames=pending,
        )

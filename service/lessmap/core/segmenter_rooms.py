"""The ``rooms`` method (``lessmap.core.rooms``) as a ``Segmenter``.

Its changes are areas' changes: an area entered, the area left and a revisit, so apps read
them as they read ``areas``'; on the wire its sessions are of the areas kind. The tracker
tests each frame as it arrives (the cut is cheap), so ``apply`` already finds the change and
``decide`` hands over what was found, oldest first (rule 3 of ``lessmap.core.segmenter``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final

from lessmap.core import segmenter_snapshot as record
from lessmap.core.areas.graph import AreaGraph, AreaGraphBuilder
from lessmap.core.closed_segments import ClosedSegments
from lessmap.core.errors import StaleFrameError
from lessmap.core.paper.params import PartitionParams
from lessmap.core.paper.partitioner import _feature_ids
from lessmap.core.rooms import snapshot as rooms_snapshot
from lessmap.core.rooms.tracker import RoomTracker
from lessmap.core.segment_change import (
    SIGHTING_EDGES,
    Method,
    SegmentChange,
    change_from,
    pack_beside,
    unpack_beside,
)

if TYPE_CHECKING:
    from collections.abc import Iterable

    from lessmap.core.paper.submaps import Submap


class RoomsSegmenter:
    """A ``RoomTracker`` and its ``AreaGraphBuilder`` as a ``Segmenter``."""

    method: Final = Method.ROOMS

    def __init__(
        self,
        tracker: RoomTracker | None = None,
        builder: AreaGraphBuilder | None = None,
        *,
        closed: Iterable[Submap] = (),
        held: Iterable[SegmentChange] = (),
        pending_frames: int = 0,
    ) -> None:
        """Wrap a tracker and the builder fed its changes so far (new ones by default)."""
        self.tracker = tracker if tracker is not None else RoomTracker()
        self.builder = builder if builder is not None else AreaGraphBuilder()
        self._closed = ClosedSegments(PartitionParams().keep_closed_submaps, closed)
        self._held: list[SegmentChange] = list(held)
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
        """Changes found, held ones included."""
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
        """Features of the open segment (what its memory grows with)."""
        return len(self.tracker.segment_counts)

    @property
    def edge_count(self) -> int:
        """Frame pairs the window compares (its similarities)."""
        n = len(self.tracker.window.frames)
        return n * (n - 1) // 2

    @property
    def memory_edges(self) -> int:
        """What the window, the segment and the area models cost, in edges."""
        return self.edge_count + SIGHTING_EDGES * (
            self.tracker.sightings + len(self.tracker.segment_counts)
        )

    @property
    def max_features_kept(self) -> int:
        """0: the rooms method keeps every feature."""
        return 0

    @property
    def closed_submaps(self) -> tuple[Submap, ...]:
        """The segments closed by the changes found, oldest first."""
        return tuple(self._closed)

    def feature_known(self, feature: int) -> bool:
        """Whether the open segment has seen a feature."""
        return self.tracker.feature_known(feature)

    def apply(self, seq: int, stamp_s: float, features: Iterable[int]) -> None:
        """Count one frame in and test it; a change found waits for ``decide``."""
        last = self.tracker.last_seq
        if last is not None and seq <= last:
            msg = f"frame seq {seq} is not after the last applied seq {last}"
            raise StaleFrameError(msg)
        ids, _ = _feature_ids(seq, features)
        found = self.tracker.observe(seq, float(stamp_s), ids)
        self._pending_frames += 1
        if found is not None:
            self.builder.add(found)
            self._closed.append(found.transition.closed)
            self._held.append(change_from(found))

    def decide(self) -> tuple[SegmentChange, ...]:
        """The changes found since the last ``decide``, oldest first."""
        changes = tuple(self._held)
        self._held.clear()
        self._pending_frames = 0
        return changes

    def current_submap(self) -> Submap:
        """The tracker's open segment."""
        return self.tracker.current_segment()

    def area_graph(self) -> AreaGraph:
        """The builder's graph, the open segment included."""
        return self.builder.graph(self.tracker)

    def to_bytes(self) -> bytes:
        """The tracker's snapshot, the builder's sums, the segments and held changes."""
        inner = rooms_snapshot.to_bytes(self.tracker)
        return pack_beside(
            Method.ROOMS, inner, self.builder, self._closed, self._held, self._pending_frames
        )

    @classmethod
    def from_record(cls, found: record.Record) -> RoomsSegmenter:
        """Rebuild from a segmenter record of the rooms method."""
        builder, closed, held, pending = unpack_beside(found)
        return cls(
            rooms_snapshot.from_bytes(found.inner),
            builder,
            closed=closed,
            held=held,
            pending_frames=pending,
        )

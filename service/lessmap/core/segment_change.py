"""What every method's segmenter reports, and how a held change is kept in a record."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any, Final

from lessmap.core import segmenter_snapshot as record
from lessmap.core.errors import GraphError
from lessmap.core.paper.submaps import Transition

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from lessmap.core.areas.events import AreaTransition
    from lessmap.core.areas.graph import AreaGraphBuilder
    from lessmap.core.closed_segments import ClosedSegments
    from lessmap.core.paper.submaps import Submap


class Method(StrEnum):
    """Which method segments a session."""

    PAPER = "paper"  # LESS-mapping's partitioner: every transition opens a new area
    AREAS = "areas"  # ``AreaTracker``: confirmed changes, recognised revisits
    ROOMS = "rooms"  # ``RoomTracker``: a windowed cut of the frames, areas named

    @property
    def wire(self) -> str:
        """The method as the wire contract names it: ``rooms`` changes are areas' changes."""
        return "paper" if self is Method.PAPER else "areas"


#: Edges' worth (24 B each, the sparse store's) of one sighting in an area model: a dict
#: entry with its own int key measures 65 B (tracemalloc, 500,000 entries).
SIGHTING_EDGES: Final = 3


@dataclass(frozen=True, slots=True, kw_only=True)
class SegmentChange:
    """The robot left one area for another: the segment closed and opened, and the areas."""

    transition: Transition  # closed / opened are segments (rule 4)
    reason: str  # "SPECTRAL", "DISCONNECTED" or "RECOGNISED" (areas only)
    area: int  # the area entered
    left_area: int  # the area left
    revisit_of: int | None  # == area when the area was known before, else None


def change_from(found: AreaTransition) -> SegmentChange:
    """A tracker's change as a segmenter's."""
    return SegmentChange(
        transition=found.transition,
        reason=found.reason.value,
        area=found.area,
        left_area=found.left_area,
        revisit_of=found.revisit_of,
    )


def change_json(change: SegmentChange) -> dict[str, Any]:
    """A held change as JSON for a segmenter record."""
    return {
        "transition": record.transition_json(change.transition),
        "reason": change.reason,
        "area": change.area,
        "left_area": change.left_area,
        "revisit_of": change.revisit_of,
    }


def change_of(d: Mapping[str, Any]) -> SegmentChange:
    """A held change back from its JSON."""
    return SegmentChange(
        transition=record.transition_of(d["transition"]),
        reason=str(d["reason"]),
        area=int(d["area"]),
        left_area=int(d["left_area"]),
        revisit_of=None if d["revisit_of"] is None else int(d["revisit_of"]),
    )


def pack_beside(
    method: Method,
    inner: bytes,
    builder: AreaGraphBuilder,
    closed: ClosedSegments,
    held: Iterable[SegmentChange],
    pending_frames: int,
) -> bytes:
    """The record of an area-naming segmenter: its tracker's bytes and what it keeps beside."""
    rows, arrays = closed.pack()
    meta: dict[str, Any] = {
        "pending_frames": pending_frames,
        "builder": record.builder_json(builder),
        "closed": rows,
        "held": [change_json(change) for change in held],
    }
    return record.pack(method, meta, inner, arrays)


def unpack_beside(
    found: record.Record,
) -> tuple[AreaGraphBuilder, list[Submap], list[SegmentChange], int]:
    """What ``pack_beside`` kept: the builder, closed segments, held changes, pending frames.

    Raises:
        GraphError: ``pending_frames`` is not a count.
    """
    meta = found.meta
    pending = meta["pending_frames"]
    if type(pending) is not int or pending < 0:
        msg = f"segmenter snapshot: pending_frames {pending!r}"
        raise GraphError(msg)
    closed = list(record.submaps_unpack(meta["closed"], found.arrays))
    held = [change_of(d) for d in meta["held"]]
    return record.builder_of(meta["builder"]), closed, held, pending

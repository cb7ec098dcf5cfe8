"""Area graphs: the areas an ``AreaTracker`` named as nodes, the robot's passages as edges.

Rules of this file (in full: ``docs/design/area-graph.md``; no I/O: graphs in, graphs out):

1. Built from the tracker's output (``AreaGraphBuilder.add`` each transition, ``graph`` at
   the end); its size grows with areas and adjacencies, never with frames or time.
2. Merges the tracker made silently are resolved when a graph is made: the sums add up and
   a passage between the two becomes a walk inside one area.
3. Nodes: frames, visits (maximal runs of segments), first and last seq, features.
4. Edges: one per unordered pair with a passage, counts per direction and boundary
   features, trimmed to the ``max_boundary_features`` most frequent (counts then bound).
5. Fleet: robot graphs merge with ``lessmap_client.fleet_areas``, online and offline alike.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from lessmap.core.areas.events import AreaTransition
    from lessmap.core.paper.submaps import Submap


class AreaModel(Protocol):
    """What a graph reads of a tracker: its areas now (``AreaTracker``, ``RoomTracker``)."""

    @property
    def current(self) -> int:
        """The area of the open segment."""

    def area_of(self, area: int) -> int:
        """The area an id stands for now."""

    def area_features(self, area: int) -> tuple[int, ...]:
        """The features an area's frames have seen."""

    def current_segment(self) -> Submap:
        """The open segment."""


#: Boundary features kept per edge (rule 4): enough to name a doorway's landmarks.
MAX_BOUNDARY_FEATURES = 16


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaNode:
    """One area of one robot (rule 3)."""

    area: int
    frames: int
    visits: int
    first_seq: int
    last_seq: int
    features: tuple[int, ...]  # ascending

    @property
    def id(self) -> int:
        """The area id (the wire's and the fleet merge's name for ``area``)."""
        return self.area


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaEdge:
    """The passages between two areas ``a < b`` (rule 4)."""

    a: int
    b: int
    a_to_b: int
    b_to_a: int
    boundary_features: tuple[tuple[int, int], ...]  # (feature, passages that reported it)

    @property
    def passages(self) -> int:
        """Passages in both directions."""
        return self.a_to_b + self.b_to_a


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaGraph:
    """One robot's areas and passages, nodes by area id, edges by (a, b)."""

    nodes: tuple[AreaNode, ...]
    edges: tuple[AreaEdge, ...]

    @property
    def areas(self) -> tuple[AreaNode, ...]:
        """The nodes, under the wire's name (``lessmap_client.fleet_areas`` reads it)."""
        return self.nodes

    @property
    def passages(self) -> tuple[AreaEdge, ...]:
        """The edges, under the wire's name (``lessmap_client.fleet_areas`` reads it)."""
        return self.edges


@dataclass(slots=True)
class _Stats:
    frames: int = 0
    visits: int = 0
    first_seq: int | None = None
    last_seq: int | None = None

    def cover(self, first: int, last: int, frames: int) -> None:
        self.frames += frames
        self.first_seq = first if self.first_seq is None else min(self.first_seq, first)
        self.last_seq = last if self.last_seq is None else max(self.last_seq, last)


class AreaGraphBuilder:
    """One robot's area graph, fed its ``AreaTransition``s. No I/O."""

    def __init__(self, max_boundary_features: int = MAX_BOUNDARY_FEATURES) -> None:
        """Start with no passages; area 0 is the tracker's first area."""
        if max_boundary_features < 0:
            msg = f"max_boundary_features must not be negative, got {max_boundary_features}"
            raise ValueError(msg)
        self.max_boundary_features = max_boundary_features
        self._areas: dict[int, _Stats] = {0: _Stats(visits=1)}
        self._passages: dict[tuple[int, int], int] = {}  # (left, entered) raw ids
        self._boundary: dict[tuple[int, int], Counter[int]] = {}  # (low, high) raw ids

    def add(self, change: AreaTransition) -> None:
        """Count one area change: the segment closed and the passage made."""
        closed = change.transition.closed
        left = self._areas.setdefault(change.left_area, _Stats())
        left.cover(closed.first_seq, closed.last_seq, closed.frame_count)
        self._areas.setdefault(change.area, _Stats()).visits += 1
        key = (change.left_area, change.area)
        self._passages[key] = self._passages.get(key, 0) + 1
        pair = (min(key), max(key))
        seen = self._boundary.setdefault(pair, Counter())
        seen.update(change.transition.boundary_features)
        if len(seen) > 2 * self.max_boundary_features:
            self._boundary[pair] = Counter(dict(_top(seen, self.max_boundary_features)))

    def graph(self, tracker: AreaModel) -> AreaGraph:
        """The graph so far, the tracker's open segment included and its merges resolved."""
        resolve = tracker.area_of
        stats: dict[int, _Stats] = {}
        for raw, part in self._areas.items():
            node = stats.setdefault(resolve(raw), _Stats())
            node.visits += part.visits
            if part.first_seq is not None and part.last_seq is not None:
                node.cover(part.first_seq, part.last_seq, part.frames)
        segment = tracker.current_segment()
        if segment.frame_count:
            current = stats.setdefault(resolve(tracker.current), _Stats(visits=1))
            current.cover(segment.first_seq, segment.last_seq, segment.frame_count)
        directed: dict[tuple[int, int], int] = {}
        boundary: dict[tuple[int, int], Counter[int]] = {}
        for (left, entered), n in self._passages.items():
            a, b = resolve(left), resolve(entered)
            if a == b:  # rule 2: two visits became one
                stats[a].visits -= n
                continue
            directed[a, b] = directed.get((a, b), 0) + n
        for (low, high), seen in self._boundary.items():
            a, b = sorted((resolve(low), resolve(high)))
            if a != b:
                boundary.setdefault((a, b), Counter()).update(seen)
        nodes = tuple(
            AreaNode(
                area=area,
                frames=s.frames,
                visits=s.visits,
                first_seq=s.first_seq if s.first_seq is not None else 0,
                last_seq=s.last_seq if s.last_seq is not None else 0,
                features=tracker.area_features(area),
            )
            for area, s in sorted(stats.items())
            if s.first_seq is not None
        )
        pairs = sorted({(min(k), max(k)) for k in directed})
        edges = tuple(
            AreaEdge(
                a=a,
                b=b,
                a_to_b=directed.get((a, b), 0),
                b_to_a=directed.get((b, a), 0),
                boundary_features=_top(boundary.get((a, b), Counter()), self.max_boundary_features),
            )
            for a, b in pairs
        )
        return AreaGraph(nodes=nodes, edges=edges)


def _top(counts: Counter[int], limit: int) -> tuple[tuple[int, int], ...]:
    """The ``limit`` most frequent features with their counts (ties: smaller id first)."""
    ranked = sorted(counts.items(), key=lambda item: (-item[1], item[0]))
    return tuple(ranked[:limit])

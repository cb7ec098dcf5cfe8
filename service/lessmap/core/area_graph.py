"""Area graphs: the areas an ``AreaTracker`` named as nodes, the robot's passages as edges.

Rules of this file:

1. **Built from the tracker's output.** ``AreaGraphBuilder.add`` takes each
   ``AreaTransition`` of one robot as it is reported; ``AreaGraphBuilder.graph`` reads the
   tracker once more (its open segment, its merges, each area's features) and returns an
   immutable ``AreaGraph``. The builder holds sums per raw area id and per raw id pair, so
   its size grows with the areas and their adjacencies, never with frames or time.
2. **Merges.** The tracker merges two areas without reporting it (its rule 6). Raw ids are
   resolved with ``tracker.area_of`` when a graph is made: the two nodes' sums add up, a
   passage between them becomes a walk inside one area (dropped), and each such passage
   joined two visits into one (``visits`` = visits of both - passages between them).
3. **Nodes.** ``frames`` counts every frame of the robot's segments in the area (empty
   frames too); ``visits`` counts maximal runs of segments in it; ``first_seq``/``last_seq``
   are the first and last frames of those segments; ``features`` are the area's features
   (``tracker.area_features``).
4. **Edges.** One per unordered pair of areas with a passage: counts per direction and the
   ``boundary_features`` of the passages (the cut edges' endpoints the proposer reported;
   a recognised change, rule 5, reports none). These are kept as counts, trimmed to the
   ``max_boundary_features`` most frequent (ties: smaller id) whenever they exceed twice
   that, so the counts of a trimmed edge are lower bounds.
5. **Fleet.** ``fleet_graph`` merges robot graphs. Without ``shared_features`` a fleet area
   is one robot's area. With it (feature ids global across the fleet's robots: fiducials,
   a shared landmark map), areas of *different* robots are linked when their feature sets
   ``A``, ``B`` have ``|A ∩ B| / min(|A|, |B|) >= min_containment`` and ``|A ∩ B| >=
   min_shared``. Links do not chain: they are taken in order of decreasing Jaccard
   ``|A ∩ B| / (|A| + |B| - |A ∩ B|)`` (ties: member order), and a link joins the fleet
   areas of its two ends only if at least ``min_linked_share`` of the pairs of areas of
   different robots across them are linked and every such pair shares ``min_shared``
   features. Why: a 360° sensor's area that sees into the next room contains both rooms'
   areas of other robots, and under union-find that one link joined the two rooms and all
   areas linked to either. Same-robot pairs are not counted (they are never linked), so a
   place one robot split in two can still be one fleet area (mrclam6's arena). Fleet ids
   count from 0 in the order of each fleet area's first member, members ordered by
   (robot name, area id): the result does not depend on the order robots are given in.

No I/O: graphs in, graphs out.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Mapping

    from lessmap.core.areas import AreaTracker
    from lessmap.core.areas_events import AreaTransition

#: Boundary features kept per edge (rule 4): enough to name a doorway's landmarks.
MAX_BOUNDARY_FEATURES = 16
#: Fleet link thresholds (rule 5), measured on simulated buildings (seeds 0-4; docs/RESULTS.md).
MIN_CONTAINMENT = 0.85
MIN_SHARED = 3
#: Share of the cross pairs that must be linked for two fleet areas to merge (rule 5). On
#: seeds 0-4 "at least half" kept every true pair; "more than half" lost 10 of 110 (270°
#: sparse) and 4 of 114 (360° sparse).
MIN_LINKED_SHARE = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaNode:
    """One area of one robot (rule 3)."""

    area: int
    frames: int
    visits: int
    first_seq: int
    last_seq: int
    features: tuple[int, ...]  # ascending


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

    def graph(self, tracker: AreaTracker) -> AreaGraph:
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


# -- the fleet -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetParams:
    """How robot areas become fleet areas (rule 5)."""

    shared_features: bool = False  # feature ids are global across the fleet's robots
    min_containment: float = MIN_CONTAINMENT
    min_shared: int = MIN_SHARED
    min_linked_share: float = MIN_LINKED_SHARE
    max_boundary_features: int = MAX_BOUNDARY_FEATURES

    def __post_init__(self) -> None:
        """Check the thresholds."""
        for name in ("min_containment", "min_linked_share"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                msg = f"{name} must be in (0, 1], got {value}"
                raise ValueError(msg)
        if self.min_shared < 1 or self.max_boundary_features < 0:
            msg = (
                f"need min_shared >= 1 and max_boundary_features >= 0, got "
                f"{self.min_shared}, {self.max_boundary_features}"
            )
            raise ValueError(msg)


Member = tuple[str, int]  # (robot, area)


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetNode:
    """One fleet area: the robot areas it stands for, and their sums."""

    area: int
    members: tuple[Member, ...]  # ascending
    frames: int
    visits: int
    features: int  # distinct features over the members


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetEdge:
    """Passages of any robot between two fleet areas ``a < b``."""

    a: int
    b: int
    a_to_b: int
    b_to_a: int
    robots: tuple[str, ...]  # robots that made them, ascending
    boundary_features: tuple[tuple[int, int], ...]

    @property
    def passages(self) -> int:
        """Passages in both directions."""
        return self.a_to_b + self.b_to_a


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetGraph:
    """The fleet's areas and passages; ``area_of[(robot, area)]`` is the fleet area."""

    nodes: tuple[FleetNode, ...]
    edges: tuple[FleetEdge, ...]
    area_of: Mapping[Member, int]


def fleet_graph(robots: Mapping[str, AreaGraph], params: FleetParams | None = None) -> FleetGraph:
    """Merge robot graphs into the fleet's (rule 5)."""
    p = params if params is not None else FleetParams()
    features = {
        (robot, node.area): frozenset(node.features)
        for robot, graph in robots.items()
        for node in graph.nodes
    }
    members = sorted(features)
    root = _roots(features, p) if p.shared_features else {m: m for m in members}
    area_of: dict[Member, int] = {}
    groups: list[list[Member]] = []
    for member in members:  # ascending: fleet ids in order of first member
        top = root[member]
        if top not in area_of:
            area_of[top] = len(groups)
            groups.append([])
        area_of[member] = area_of[top]
        groups[area_of[member]].append(member)
    nodes_by = {(robot, node.area): node for robot, g in robots.items() for node in g.nodes}
    nodes = tuple(
        FleetNode(
            area=index,
            members=tuple(group),
            frames=sum(nodes_by[m].frames for m in group),
            visits=sum(nodes_by[m].visits for m in group),
            features=len({f for m in group for f in features[m]}),
        )
        for index, group in enumerate(groups)
    )
    return FleetGraph(nodes=nodes, edges=_fleet_edges(robots, area_of, p), area_of=area_of)


def _roots(features: Mapping[Member, frozenset[int]], p: FleetParams) -> dict[Member, Member]:
    """Each area's fleet area, named by its smallest member (rule 5: links do not chain)."""
    shared = _shared(features)
    linked = [
        pair
        for pair, n in shared.items()
        if n >= p.min_shared
        and n >= p.min_containment * min(len(features[pair[0]]), len(features[pair[1]]))
    ]
    is_link = set(linked)

    def jaccard(pair: tuple[Member, Member]) -> float:
        n = shared[pair]
        return n / (len(features[pair[0]]) + len(features[pair[1]]) - n)

    # Closest pairs first: an area that also sees into the next room is a weaker (lower
    # Jaccard) partner than its own room's areas, which have joined before it is reached.
    linked.sort(key=lambda pair: (-jaccard(pair), pair))
    root = {m: m for m in features}
    groups = {m: [m] for m in features}
    for x, y in linked:
        rx, ry = root[x], root[y]
        if rx == ry:
            continue
        cross = [(min(a, b), max(a, b)) for a in groups[rx] for b in groups[ry] if a[0] != b[0]]
        if sum(pair in is_link for pair in cross) < p.min_linked_share * len(cross):
            continue
        if any(shared.get(pair, 0) < p.min_shared for pair in cross):
            continue  # a chain's ends that share nothing stay apart, whatever the share
        keep, gone = min(rx, ry), max(rx, ry)  # the smaller root stays: no order bias
        for member in groups[gone]:
            root[member] = keep
        groups[keep] += groups.pop(gone)
    return root


def _shared(features: Mapping[Member, frozenset[int]]) -> Counter[tuple[Member, Member]]:
    """Features shared by each pair ``x < y`` of areas of different robots sharing any.

    Found through an inverted index (feature -> areas), so only pairs sharing a feature are
    compared: a fleet of many robots does not pay for every pair of areas.
    """
    holders: dict[int, list[Member]] = {}
    for member in sorted(features):
        for feature in features[member]:
            holders.setdefault(feature, []).append(member)
    shared: Counter[tuple[Member, Member]] = Counter()
    for group in holders.values():
        for i, x in enumerate(group):
            for y in group[i + 1 :]:
                if x[0] != y[0]:
                    shared[x, y] += 1
    return shared


def _fleet_edges(
    robots: Mapping[str, AreaGraph], area_of: Mapping[Member, int], p: FleetParams
) -> tuple[FleetEdge, ...]:
    directed: dict[tuple[int, int], int] = {}
    makers: dict[tuple[int, int], set[str]] = {}
    boundary: dict[tuple[int, int], Counter[int]] = {}
    for robot, graph in robots.items():
        for edge in graph.edges:
            a, b = area_of[robot, edge.a], area_of[robot, edge.b]
            if a == b:  # one fleet area: a walk inside it
                continue
            directed[a, b] = directed.get((a, b), 0) + edge.a_to_b
            directed[b, a] = directed.get((b, a), 0) + edge.b_to_a
            pair = (min(a, b), max(a, b))
            makers.setdefault(pair, set()).add(robot)
            boundary.setdefault(pair, Counter()).update(dict(edge.boundary_features))
    return tuple(
        FleetEdge(
            a=a,
            b=b,
            a_to_b=directed.get((a, b), 0),
            b_to_a=directed.get((b, a), 0),
            robots=tuple(sorted(makers[a, b])),
            boundary_features=_top(boundary[a, b], p.max_boundary_features),
        )
        for a, b in sorted(makers)
    )

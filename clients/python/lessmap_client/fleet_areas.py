"""Fleet areas: the robots' area graphs merged into one graph of the fleet's places.

``fleet_graph`` is pure (graphs in, graph out, no I/O), so a fleet app (over the bus) and the
offline tools (from a frames file) compute the same fleet areas where the robots' graphs
meet. Rules (in full, with why: ``docs/design/fleet-areas.md``):

1. A fleet area stands for robot areas, each named ``(robot, area id)``.
2. Without ``shared_features`` a fleet area is one robot's area.
3. With ``shared_features``, areas of different robots are linked by containment and shared
   features, closest pairs (Jaccard) first; a link joins two fleet areas only if at least
   ``min_linked_share`` of their cross pairs are linked, so one wrong link does not chain.
4. Fleet ids count from 0 in member order (robot name, area id), whatever the robot order;
   across graphs a fleet area is named by its first member (``FleetGraph.key_of``).
5. Passages between fleet areas count per direction; one inside a fleet area is dropped.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

#: Boundary features kept per fleet passage (rule 5): enough to name a doorway's landmarks.
MAX_BOUNDARY_FEATURES = 16
#: Link thresholds (rule 3), chosen on simulated buildings (docs/tuning/fleet-areas.md).
MIN_CONTAINMENT = 0.85
MIN_SHARED = 3
#: Share of the cross pairs that must be linked for two fleet areas to merge (rule 3): the
#: loosest that stops one wrong link from chaining two rooms (docs/tuning/fleet-areas.md).
MIN_LINKED_SHARE = 0.5


class RobotArea(Protocol):
    """What the merge reads of a robot's area (``lessmap_schemas.messages.AreaNode``)."""

    @property
    def id(self) -> int:
        """Area id within the session."""

    @property
    def frames(self) -> int:
        """Frames in the area."""

    @property
    def visits(self) -> int:
        """Separate stays in the area."""

    @property
    def features(self) -> Sequence[int]:
        """Distinct feature ids of the area."""


class RobotPassage(Protocol):
    """What the merge reads of a robot's passage (``lessmap_schemas.messages.Passage``)."""

    @property
    def a(self) -> int:
        """Lower area id."""

    @property
    def b(self) -> int:
        """Higher area id."""

    @property
    def a_to_b(self) -> int:
        """Passages from a to b."""

    @property
    def b_to_a(self) -> int:
        """Passages from b to a."""

    @property
    def boundary_features(self) -> Sequence[tuple[int, int]]:
        """(feature id, passages that reported it)."""


class RobotAreaGraph(Protocol):
    """A robot's areas and passages (``lessmap_schemas.messages.AreaGraph``)."""

    @property
    def areas(self) -> Sequence[RobotArea]:
        """Areas by ascending id."""

    @property
    def passages(self) -> Sequence[RobotPassage]:
        """Passages by ascending (a, b)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetParams:
    """How robot areas become fleet areas (rule 3)."""

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


Member = tuple[str, int]  # (robot, area id)


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

    def key_of(self, robot: str, area: int) -> Member:
        """The name of the robot area's fleet area that outlives this graph (rule 4).

        The fleet area's first member, ``(robot, area id)``: later graphs keep it while the
        fleet area exists, and when two fleet areas are found to be one the lower member
        names both (as a robot's merged areas keep the lower id).
        """
        return self.nodes[self.area_of[robot, area]].members[0]

    def members_of(self, area: int) -> tuple[Member, ...]:
        """The robot areas of fleet area ``area``."""
        return self.nodes[area].members

    def to_json(self) -> dict[str, Any]:
        """The nodes and edges as JSON-ready lists (the area-graph file's and the vectors')."""
        return {
            "nodes": [
                {
                    "area": n.area,
                    "members": [list(m) for m in n.members],
                    "frames": n.frames,
                    "visits": n.visits,
                    "features": n.features,
                }
                for n in self.nodes
            ],
            "edges": [
                {
                    "a": e.a,
                    "b": e.b,
                    "a_to_b": e.a_to_b,
                    "b_to_a": e.b_to_a,
                    "boundary_features": [list(pair) for pair in e.boundary_features],
                    "robots": list(e.robots),
                }
                for e in self.edges
            ],
        }

    def robots_in(self, area: int) -> tuple[str, ...]:
        """The robots that have been in fleet area ``area``, ascending."""
        return tuple(sorted({robot for robot, _ in self.nodes[area].members}))


def fleet_graph(
    robots: Mapping[str, RobotAreaGraph], params: FleetParams | None = None
) -> FleetGraph:
    """Merge robot graphs (robot name -> its graph) into the fleet's (module rules)."""
    p = params if params is not None else FleetParams()
    features = {
        (robot, area.id): frozenset(area.features)
        for robot, graph in robots.items()
        for area in graph.areas
    }
    members = sorted(features)
    root = _roots(features, p) if p.shared_features else {m: m for m in members}
    area_of: dict[Member, int] = {}
    groups: list[list[Member]] = []
    for member in members:  # ascending: fleet ids in order of first member (rule 4)
        top = root[member]
        if top not in area_of:
            area_of[top] = len(groups)
            groups.append([])
        area_of[member] = area_of[top]
        groups[area_of[member]].append(member)
    areas_by = {(robot, area.id): area for robot, g in robots.items() for area in g.areas}
    nodes = tuple(
        FleetNode(
            area=index,
            members=tuple(group),
            frames=sum(areas_by[m].frames for m in group),
            visits=sum(areas_by[m].visits for m in group),
            features=len({f for m in group for f in features[m]}),
        )
        for index, group in enumerate(groups)
    )
    return FleetGraph(nodes=nodes, edges=_fleet_edges(robots, area_of, p), area_of=area_of)


def fleet_graph_of(
    graphs: Iterable[RobotAreaGraphMessage], params: FleetParams | None = None
) -> FleetGraph:
    """Merge area graph replies (``AreaGraph`` messages of one fleet) by their robot names."""
    by_robot: dict[str, RobotAreaGraph] = {}
    fleets: set[str] = set()
    for graph in graphs:
        fleets.add(graph.fleet)
        if graph.robot in by_robot:
            msg = f"two area graphs for robot {graph.robot!r}: merge one per robot"
            raise ValueError(msg)
        by_robot[graph.robot] = graph
    if len(fleets) > 1:
        msg = f"area graphs of several fleets ({', '.join(sorted(fleets))}): merge one fleet"
        raise ValueError(msg)
    return fleet_graph(by_robot, params)


class RobotAreaGraphMessage(RobotAreaGraph, Protocol):
    """An area graph that names its fleet and robot (an ``AreaGraph`` reply)."""

    @property
    def fleet(self) -> str:
        """Fleet of the robot."""

    @property
    def robot(self) -> str:
        """The robot."""


def _roots(features: Mapping[Member, frozenset[int]], p: FleetParams) -> dict[Member, Member]:
    """Each area's fleet area, named by its smallest member (rule 3: links do not chain)."""
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
    robots: Mapping[str, RobotAreaGraph], area_of: Mapping[Member, int], p: FleetParams
) -> tuple[FleetEdge, ...]:
    directed: dict[tuple[int, int], int] = {}
    makers: dict[tuple[int, int], set[str]] = {}
    boundary: dict[tuple[int, int], Counter[int]] = {}
    for robot, graph in robots.items():
        for passage in graph.passages:
            a, b = area_of[robot, passage.a], area_of[robot, passage.b]
            if a == b:  # one fleet area: a walk inside it
                continue
            directed[a, b] = directed.get((a, b), 0) + passage.a_to_b
            directed[b, a] = directed.get((b, a), 0) + passage.b_to_a
            pair = (min(a, b), max(a, b))
            makers.setdefault(pair, set()).add(robot)
            boundary.setdefault(pair, Counter()).update(dict(passage.boundary_features))
    return tuple(
        FleetEdge(
            a=a,
            b=b,
            a_to_b=directed.get((a, b), 0),
            b_to_a=directed.get((b, a), 0),
            robots=tuple(sorted(makers[a, b])),
            boundary_features=top_counts(boundary[a, b], p.max_boundary_features),
        )
        for a, b in sorted(makers)
    )


def top_counts(counts: Counter[int], limit: int) -> tuple[tuple[int, int], ...]:
    """The ``limit`` most frequent features with their counts (ties: smaller id first)."""
    ranked = sorted(counts.items(), key=lambda item: (-item[1], item[0]))
    return tuple(ranked[:limit])

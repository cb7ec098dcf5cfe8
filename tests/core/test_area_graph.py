"""Area graphs: nodes and passages from an AreaTracker's changes, and the fleet merge of them
(``lessmap_client.fleet_areas`` reads the core's graphs as it reads the wire's)."""

from __future__ import annotations

import itertools

import pytest

from lessmap.core.areas.graph import AreaEdge, AreaGraph, AreaGraphBuilder, AreaNode
from lessmap.core.areas.tracker import AreaTracker, AreaTransition
from lessmap.core.paper.submaps import Reason, Submap, Transition
from lessmap_client.fleet_areas import FleetParams, fleet_graph
from tests.core.helpers import Frames, room_walk


def build(frames: Frames, builder: AreaGraphBuilder | None = None) -> tuple[AreaGraph, AreaTracker]:
    tracker = AreaTracker()
    builder = builder if builder is not None else AreaGraphBuilder()
    for seq, frame in enumerate(frames):
        change = tracker.observe(seq, seq * 0.1, frame)
        if change is not None:
            builder.add(change)
    return builder.graph(tracker), tracker


@pytest.mark.parametrize("seed", range(3))
def test_a_walk_there_and_back_is_a_path_of_areas_crossed_twice(seed: int) -> None:
    walk = room_walk(seed, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    graph, tracker = build(walk.frames)
    # route 0 1 2 3 2 1 0: four areas in a row, each door crossed once each way
    assert [n.area for n in graph.nodes] == [0, 1, 2, 3]
    assert [(e.a, e.b, e.a_to_b, e.b_to_a) for e in graph.edges] == [
        (0, 1, 1, 1),
        (1, 2, 1, 1),
        (2, 3, 1, 1),
    ]
    assert [n.visits for n in graph.nodes] == [2, 2, 2, 1]
    assert sum(n.frames for n in graph.nodes) == len(walk.frames)
    assert graph.nodes[0].first_seq == 0
    assert max(n.last_seq for n in graph.nodes) == len(walk.frames) - 1
    for node in graph.nodes:
        assert node.features == tracker.area_features(node.area)
    for edge in graph.edges:  # a door's boundary features are landmarks of its two rooms
        rooms = walk.rooms[edge.a] | walk.rooms[edge.b]
        assert {f for f, _ in edge.boundary_features} <= rooms


def test_frames_and_seqs_follow_the_segments() -> None:
    walk = room_walk(7, rooms=3, stay=(25, 25), door_frames=1, door_share=0.1)
    graph, _ = build(walk.frames)
    assert len(graph.nodes) == 3
    for node, start, end in zip(
        graph.nodes, (0, *walk.doors), (*walk.doors, len(walk.frames)), strict=True
    ):
        assert node.first_seq == pytest.approx(start, abs=2)
        assert node.last_seq == pytest.approx(end - 1, abs=2)
        assert node.frames == node.last_seq - node.first_seq + 1


def test_an_empty_tracker_has_an_empty_graph() -> None:
    assert AreaGraphBuilder().graph(AreaTracker()) == AreaGraph(nodes=(), edges=())


def change(left: int, entered: int, boundary: int, features: tuple[int, ...]) -> AreaTransition:
    """A reported change from ``left`` to ``entered`` at ``boundary`` (10 frames a segment)."""
    closed = Submap(
        id=0, first_seq=boundary - 10, last_seq=boundary - 1, frame_count=10, features=()
    )
    opened = Submap(id=1, first_seq=boundary, last_seq=boundary, frame_count=1, features=())
    transition = Transition(
        seq=boundary,
        boundary_seq=boundary,
        stamp_s=0.0,
        reason=Reason.SPECTRAL,
        ncut=0.1,
        lambda2=0.5,
        closed=closed,
        opened=opened,
        boundary_features=features,
        batch_frames=1,
    )
    return AreaTransition(
        transition=transition, area=entered, left_area=left, revisit_of=None, overlap=0.0
    )


def test_boundary_features_are_counted_and_bounded() -> None:
    builder = AreaGraphBuilder(max_boundary_features=3)
    tracker = AreaTracker()
    true: dict[int, int] = {}
    for k in range(12):  # 0 <-> 1, feature 100 at every passage, 200 + k once each
        left, entered = (0, 1) if k % 2 == 0 else (1, 0)
        features = (100, 200 + k, 101 if k < 4 else 300)
        builder.add(change(left, entered, 10 * (k + 1), features))
        for feature in features:
            true[feature] = true.get(feature, 0) + 1
    tracker.areas.append({})  # area 1 exists for the tracker too
    tracker.area_frames.append(0)
    (edge,) = builder.graph(tracker).edges
    assert (edge.a, edge.b, edge.a_to_b, edge.b_to_a) == (0, 1, 6, 6)
    assert edge.boundary_features[0] == (100, 12)  # never trimmed: exact
    assert len(edge.boundary_features) == 3
    counts = [n for _, n in edge.boundary_features]
    assert counts == sorted(counts, reverse=True)
    assert all(n <= true[feature] for feature, n in edge.boundary_features)  # lower bounds
    assert 300 in dict(edge.boundary_features)  # the later frequent one climbs back in


def test_merged_areas_become_one_node_and_their_passages_vanish() -> None:
    builder = AreaGraphBuilder()
    tracker = AreaTracker()
    builder.add(change(0, 1, 10, (1,)))
    builder.add(change(1, 2, 20, (2,)))
    builder.add(change(2, 1, 30, (3,)))
    for _ in range(2):
        tracker.areas.append({})
        tracker.area_frames.append(0)
    assert [n.visits for n in builder.graph(tracker).nodes] == [1, 2, 1]
    tracker.merged[2] = 1  # rule 6 merged area 2 into 1, unreported
    graph = builder.graph(tracker)
    # 0 -> 1 -> 2 -> 1 is now 0 -> 1 (one visit): frames of 1 and 2 add up
    assert graph.nodes == (
        AreaNode(area=0, frames=10, visits=1, first_seq=0, last_seq=9, features=()),
        AreaNode(area=1, frames=20, visits=1, first_seq=10, last_seq=29, features=()),
    )
    assert graph.edges == (AreaEdge(a=0, b=1, a_to_b=1, b_to_a=0, boundary_features=((1, 1),)),)


# -- the fleet -------------------------------------------------------------------------------


def node(area: int, features: range | tuple[int, ...], frames: int = 10) -> AreaNode:
    return AreaNode(
        area=area,
        frames=frames,
        visits=1,
        first_seq=0,
        last_seq=frames - 1,
        features=tuple(features),
    )


def edge(a: int, b: int, n: int = 1) -> AreaEdge:
    return AreaEdge(a=a, b=b, a_to_b=n, b_to_a=0, boundary_features=((a * 100 + b, n),))


ROOM_A, ROOM_B, ROOM_C = range(20), range(100, 120), range(200, 220)
ROBOTS = {
    # r1 walked A -> B; r2 B -> C, seeing most of B; r3 only C, and a few of A's landmarks
    "r1": AreaGraph(nodes=(node(0, ROOM_A), node(1, ROOM_B)), edges=(edge(0, 1),)),
    "r2": AreaGraph(nodes=(node(0, ROOM_B[:15]), node(1, ROOM_C)), edges=(edge(0, 1, 2),)),
    "r3": AreaGraph(nodes=(node(0, (*ROOM_C, *ROOM_A[:2])),), edges=()),
}


def test_without_shared_features_each_robot_area_is_a_fleet_area() -> None:
    fleet = fleet_graph(ROBOTS)
    assert [n.members for n in fleet.nodes] == [
        (("r1", 0),),
        (("r1", 1),),
        (("r2", 0),),
        (("r2", 1),),
        (("r3", 0),),
    ]
    assert [(e.a, e.b, e.passages, e.robots) for e in fleet.edges] == [
        (0, 1, 1, ("r1",)),
        (2, 3, 2, ("r2",)),
    ]


def test_shared_features_give_robots_in_one_room_one_fleet_area() -> None:
    fleet = fleet_graph(ROBOTS, FleetParams(shared_features=True))
    # B: r2 saw 15 of r1's 20 (containment 1.0); C: r3 holds all of r2's C (20/20)
    assert [n.members for n in fleet.nodes] == [
        (("r1", 0),),
        (("r1", 1), ("r2", 0)),
        (("r2", 1), ("r3", 0)),
    ]
    assert [n.frames for n in fleet.nodes] == [10, 20, 20]
    assert [n.features for n in fleet.nodes] == [20, 20, 22]
    assert [(e.a, e.b, e.a_to_b, e.b_to_a, e.robots) for e in fleet.edges] == [
        (0, 1, 1, 0, ("r1",)),
        (1, 2, 2, 0, ("r2",)),
    ]
    assert fleet.area_of["r3", 0] == 2


def test_containment_and_shared_floor_decide_a_link() -> None:
    two = {
        "r1": AreaGraph(nodes=(node(0, range(10)),), edges=()),
        "r2": AreaGraph(nodes=(node(0, range(2, 12)),), edges=()),  # 8 of 10 shared
    }
    linked = FleetParams(shared_features=True, min_containment=0.8)
    apart = FleetParams(shared_features=True, min_containment=0.81)
    assert len(fleet_graph(two, linked).nodes) == 1
    assert len(fleet_graph(two, apart).nodes) == 2
    floor = FleetParams(shared_features=True, min_containment=0.5, min_shared=9)
    assert len(fleet_graph(two, floor).nodes) == 2


def test_areas_of_one_robot_are_never_linked_directly() -> None:
    one = {"r1": AreaGraph(nodes=(node(0, range(10)), node(1, range(10))), edges=(edge(0, 1),))}
    fleet = fleet_graph(one, FleetParams(shared_features=True))
    assert len(fleet.nodes) == 2
    assert len(fleet.edges) == 1


@pytest.mark.parametrize("shared", [False, True])
def test_the_merge_does_not_depend_on_robot_order(shared: bool) -> None:
    params = FleetParams(shared_features=shared)
    expected = fleet_graph(ROBOTS, params)
    for order in itertools.permutations(ROBOTS):
        assert fleet_graph({robot: ROBOTS[robot] for robot in order}, params) == expected


@pytest.mark.parametrize(
    "params",
    [
        {"min_containment": 0.0},
        {"min_containment": 1.5},
        {"min_linked_share": 0.0},
        {"min_shared": 0},
        {"max_boundary_features": -1},
    ],
)
def test_bad_fleet_params_are_refused(params: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(params))):
        FleetParams(**params)  # type: ignore[arg-type]


def shared_fleet(robots: dict[str, AreaGraph]) -> list[tuple[tuple[str, int], ...]]:
    """The fleet areas' members with shared features; the same for every robot order."""
    params = FleetParams(shared_features=True)
    fleet = fleet_graph(robots, params)
    for order in itertools.permutations(robots):
        assert fleet_graph({robot: robots[robot] for robot in order}, params) == fleet
    return [n.members for n in fleet.nodes]


def test_links_do_not_chain_ends_that_share_nothing() -> None:
    # r2's area holds both r1's and r3's (containment 1), which share no feature
    chain = {
        "r1": AreaGraph(nodes=(node(0, range(8)),), edges=()),
        "r2": AreaGraph(nodes=(node(0, range(20)),), edges=()),
        "r3": AreaGraph(nodes=(node(0, range(10, 20)),), edges=()),
    }
    assert shared_fleet(chain) == [(("r1", 0),), (("r2", 0), ("r3", 0))]  # closer pair joins


def test_an_area_seeing_into_the_next_room_does_not_join_the_rooms() -> None:
    room_p, room_q = range(10), range(20, 32)
    both = {
        "r1": AreaGraph(nodes=(node(0, room_p), node(1, room_q[:10])), edges=(edge(0, 1),)),
        "r2": AreaGraph(nodes=(node(0, room_p), node(1, room_q)), edges=(edge(0, 1),)),
        # a 360° sensor in Q sees P through the door: both rooms' areas are contained in it
        "r3": AreaGraph(nodes=(node(0, (*room_p, *room_q)),), edges=()),
    }
    assert shared_fleet(both) == [
        (("r1", 0), ("r2", 0)),
        (("r1", 1), ("r2", 1), ("r3", 0)),  # its larger overlap, with Q
    ]


def test_a_place_one_robot_split_in_two_is_still_one_fleet_area() -> None:
    # as in mrclam6's arena: r2 and r3 each split it, r1 saw it whole
    arena = range(15)
    split = {
        "r1": AreaGraph(nodes=(node(0, arena),), edges=()),
        "r2": AreaGraph(nodes=(node(0, arena[8:]), node(1, arena)), edges=(edge(0, 1),)),
        "r3": AreaGraph(nodes=(node(0, arena[:12]), node(1, arena[6:])), edges=(edge(0, 1),)),
    }
    assert len(shared_fleet(split)) == 1

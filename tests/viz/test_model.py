"""The viewer's model of a fleet: submaps by boundary, poses, the CovGraph of a submap."""

from __future__ import annotations

import pytest

from lessmap.viz.model import FleetModel, covgraph_of
from lessmap.viz.scene import color, doorways, robot_entities, track_entities
from lessmap_schemas.messages import Frame, SubmapSummary, Transition
from tests.viz.conftest import decode


def transition(robot: str, session: str, boundary: int, opened: int) -> Transition:
    summary = SubmapSummary(
        id=opened - 1, first_seq=0, last_seq=boundary - 1, frame_count=1, features=[]
    )
    return Transition(
        fleet="f",
        robot=robot,
        session=session,
        incarnation=0,
        seq=boundary + 2,
        boundary_seq=boundary,
        stamp_s=1.0,
        reason="DISCONNECTED",
        ncut=None,
        lambda2=None,
        closed=summary,
        opened=SubmapSummary(
            id=opened, first_seq=boundary, last_seq=boundary + 2, frame_count=3, features=[]
        ),
        boundary_features=[],
        area=opened,
        left_area=opened - 1,
        revisit=False,
        batch_frames=1,
        instance="i",
        partition=0,
        epoch=1,
    )


def test_submaps_follow_the_boundaries_and_marks_sit_at_the_boundary_pose() -> None:
    model = FleetModel("f")
    for seq in range(10):
        model.on_frame(
            "r", Frame(session="s1", seq=seq, stamp_s=seq, features=[seq], pose=(seq, 0.0, 0.0))
        )
    mark = model.on_transition(transition("r", "s1", 4, 1))
    assert mark is not None
    assert mark.at is not None
    assert mark.at.x == 4
    assert model.on_transition(transition("r", "s1", 4, 1)) is None  # a repeat
    model.on_transition(transition("r", "s1", 7, 2))
    track = model.tracks["r"]
    assert [track.submap_of(seq) for seq in range(10)] == [0] * 4 + [1] * 3 + [2] * 3
    # An older session's transition (history) does not replace the robot's current track.
    assert model.on_transition(transition("r", "s0", 2, 1)) is None
    assert model.tracks["r"].session == "s1"
    # A new session starts a new track.
    model.on_frame("r", Frame(session="s2", seq=0, stamp_s=20.0, features=[1]))
    assert model.tracks["r"].session == "s2"
    assert model.tracks["r"].marks == []


def test_the_covgraph_counts_covisibility_and_covrate() -> None:
    frames = [((1, 2, 3), (0.0, 0.0)), ((2, 3), (2.0, 0.0)), ((3, 4), None)]
    graph = covgraph_of(frames, max_nodes=10)
    assert {f: n for f, (n, _) in graph.nodes.items()} == {1: 1, 2: 2, 3: 3, 4: 1}
    assert graph.nodes[2][1] == pytest.approx((1.0, 0.0))  # mean pose of the frames seeing it
    assert graph.nodes[4][1] is None  # seen only without a pose
    # W_ij = a_ij / min(n_i, n_j) (the paper's Eq. 1)
    assert graph.edges[(2, 3)] == pytest.approx((2, 1.0))
    assert graph.edges[(3, 4)] == pytest.approx((1, 1.0))
    assert graph.edges[(1, 3)] == pytest.approx((1, 1.0))
    assert graph.edges[(1, 2)] == pytest.approx((1, 1.0))
    assert covgraph_of(frames, max_nodes=1).nodes.keys() == {3}  # the most seen features
    sparse = covgraph_of([((1, 2), None), ((1,), None), ((2,), None), ((1,), None)], 10)
    assert sparse.edges[(1, 2)] == pytest.approx((1, 0.5))  # a_12 = 1, n_1 = 3, n_2 = 2


def walk_frames(session: str, xs: range, y: float = 0.0) -> list[Frame]:
    return [
        Frame(session=session, seq=seq, stamp_s=float(seq), features=[seq], pose=(x, y, 0.0))
        for seq, x in enumerate(xs)
    ]


def test_a_new_session_starts_a_new_track_and_the_left_one_is_drawn_dimmed() -> None:
    model = FleetModel("f")
    for frame in walk_frames("s1", range(10)):
        model.on_frame("r", frame)
    assert model.on_transition(transition("r", "s1", 4, 1)) is not None
    # The same robot name, a new run: its frames start at seq 0 in a new session.
    for frame in walk_frames("s2", range(100, 103)):
        assert model.on_frame("r", frame) is not None
    track = model.tracks["r"]
    assert track.session == "s2"
    assert [p.x for p in track.points] == [100, 101, 102]  # not appended to s1's line
    assert track.marks == []
    assert [track.submap_of(seq) for seq in range(3)] == [0, 0, 0]
    assert model.previous["r"].session == "s1"
    assert len(model.previous["r"].points) == 10
    # Late frames and transitions of the session the robot left change nothing.
    assert model.on_frame("r", walk_frames("s1", range(11))[10]) is None
    assert model.on_transition(transition("r", "s1", 8, 2)) is None
    assert model.tracks["r"].session == "s2"
    assert len(model.previous["r"].points) == 10

    entities = {e["id"]: e for e in map(decode, robot_entities(model, "r"))}
    assert set(entities) == {"r/trajectory", "r/previous"}
    (current,) = entities["r/trajectory"]["lines"]
    assert [p["x"] for p in current["points"]] == [100, 101, 102]
    assert {c["b"] for c in current["colors"]} == {decode(color(0))["b"]}  # submap 0 again
    previous = entities["r/previous"]
    (line,) = previous["lines"]
    assert [p["x"] for p in line["points"]] == list(range(10))
    assert line["colors"] == []  # one dimmed grey: s1's submaps are not s2's
    assert line["color"]["a"] < 0.5
    assert line["thickness"] < current["thickness"]
    assert previous["texts"] == []
    assert previous["spheres"] == []
    # s1's transition is no longer drawn: the doorways are the current sessions'.
    assert doorways(model.tracks.values()) == []

    # A third session: the second becomes the one drawn dimmed, the first is dropped.
    model.on_frame("r", walk_frames("s3", range(200, 201))[0])
    assert model.previous["r"].session == "s2"
    assert [p.x for p in model.previous["r"].points] == [100, 101, 102]


def test_a_session_without_poses_yet_clears_the_robots_line() -> None:
    model = FleetModel("f")
    for frame in walk_frames("s1", range(5)):
        model.on_frame("r", frame)
    model.on_frame("r", Frame(session="s2", seq=0, stamp_s=0.0, features=[1]))  # no pose
    (entity,) = map(decode, track_entities(model.tracks["r"]))
    assert entity["id"] == "r/trajectory"  # replaces the s1 line a client still shows
    assert entity["lines"] == []
    assert entity["spheres"] == []
    assert entity["texts"] == []

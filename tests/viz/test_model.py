"""The viewer's model of a fleet: submaps by boundary, poses, the CovGraph of a submap."""

from __future__ import annotations

import pytest

from lessmap.viz.model import FleetModel, covgraph_of
from lessmap_schemas.messages import Frame, SubmapSummary, Transition


def transition(robot: str, session: str, boundary: int, opened: int) -> Transition:
    summary = SubmapSummary(
        id=opened - 1, first_seq=0, last_seq=boundary - 1, frame_count=1, features=[]
    )
    return Transition(
        fleet="f",
        robot=robot,
        session=session,
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

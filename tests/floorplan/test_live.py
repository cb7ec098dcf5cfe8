"""A running fleet's trajectories for its room map (``floorplan.live``), message by message."""

from __future__ import annotations

import numpy as np
import pytest

from lessmap.floorplan.live import LiveTrajectories
from lessmap_schemas.messages import Frame, SubmapSummary, Transition


def frame(seq: int, session: str = "s", *, pose: bool = True) -> Frame:
    return Frame(
        session=session,
        seq=seq,
        stamp_s=seq / 10,
        features=[seq],
        pose=(seq * 0.1, 1.0, 0.0) if pose else None,
    )


def transition(
    boundary: int, area: int, *, closed: int, incarnation: int = 0, session: str = "s"
) -> Transition:
    return Transition(
        fleet="f",
        robot="r",
        session=session,
        incarnation=incarnation,
        seq=boundary + 2,
        boundary_seq=boundary,
        stamp_s=1.0,
        reason="DISCONNECTED",
        ncut=None,
        lambda2=None,
        closed=SubmapSummary(
            id=closed, first_seq=incarnation, last_seq=incarnation, frame_count=1, features=[]
        ),
        opened=SubmapSummary(
            id=closed + 1, first_seq=boundary, last_seq=boundary, frame_count=1, features=[]
        ),
        boundary_features=[],
        area=area,
        left_area=area + 1,
        revisit=False,
        batch_frames=1,
        instance="i",
        partition=0,
        epoch=1,
    )


def test_each_pose_takes_the_area_of_the_last_boundary_before_it() -> None:
    live = LiveTrajectories()
    for seq in range(10):
        live.add_frame("r", frame(seq))
    live.add_transition(transition(4, area=3, closed=0))
    live.add_transition(transition(7, area=0, closed=1))
    [track] = live.tracks()
    assert track.name == "r/s"
    assert track.seqs.tolist() == list(range(10))
    assert track.areas.tolist() == [0, 0, 0, 0, 3, 3, 3, 0, 0, 0]
    assert np.allclose(track.xy[:, 0], np.arange(10) * 0.1)


def test_a_resent_transition_counts_once_and_repeated_frames_are_dropped() -> None:
    live = LiveTrajectories()
    for seq in (0, 1, 2, 2, 1, 3):
        live.add_frame("r", frame(seq))
    live.add_frame("r", frame(4, pose=False))
    for _ in range(3):
        live.add_transition(transition(2, area=1, closed=0))
    [track] = live.tracks()
    assert track.seqs.tolist() == [0, 1, 2, 3]
    assert track.areas.tolist() == [0, 0, 1, 1]
    assert live.counts["frames repeated or out of order"] == 2
    assert live.counts["frames without a pose"] == 1
    assert live.counts["transitions repeated"] == 2


def test_a_new_incarnation_is_a_track_of_its_own() -> None:
    live = LiveTrajectories()
    for seq in range(12):
        live.add_frame("r", frame(seq))
    live.add_transition(transition(3, area=1, closed=0))
    # state lost: the history restarts at seq 6 and its areas are numbered afresh
    live.add_transition(transition(9, area=1, closed=0, incarnation=6))
    first, second = live.tracks()
    assert (first.name, second.name) == ("r/s", "r/s#6")
    assert first.seqs.tolist() == [0, 1, 2, 3, 4, 5]
    assert first.areas.tolist() == [0, 0, 0, 1, 1, 1]
    assert second.seqs.tolist() == [6, 7, 8, 9, 10, 11]
    assert second.areas.tolist() == [0, 0, 0, 1, 1, 1]


def test_a_full_session_keeps_its_whole_walk_at_a_coarser_step() -> None:
    live = LiveTrajectories(max_poses_per_session=8)
    for seq in range(40):
        live.add_frame("r", frame(seq))
    [track] = live.tracks()
    assert track.seqs.size < 8
    assert track.seqs[0] == 0  # the start and the end are both still there
    assert track.seqs[-1] >= 32
    assert np.all(np.diff(track.seqs) > 0)
    assert live.counts["sessions thinned"] >= 2


def test_sessions_beyond_the_bound_drop_the_stalest() -> None:
    live = LiveTrajectories(max_sessions=2)
    live.add_frame("r", frame(0, "a"))
    live.add_frame("r", frame(0, "b"))
    live.add_frame("r", frame(1, "a"))  # b is now the stalest
    live.add_frame("r", frame(0, "c"))
    assert [t.name for t in live.tracks()] == ["r/a", "r/c"]
    assert live.counts["sessions dropped (too many)"] == 1


@pytest.mark.parametrize(("poses", "sessions"), [(1, 1), (8, 0)])
def test_bounds_are_checked(poses: int, sessions: int) -> None:
    with pytest.raises(ValueError, match="max_poses_per_session"):
        LiveTrajectories(max_poses_per_session=poses, max_sessions=sessions)

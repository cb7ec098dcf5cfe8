"""Synthetic walks through rooms in a row: one transition per door, none elsewhere.

The walk generator is ``tests.core.helpers.room_walk`` (seeded numpy rng; shared with the
snapshot tests): R rooms with 15-30 landmarks each, every frame sees 60-90 % of the current
room, frames next to a door also see part of the room on the other side.
"""

from __future__ import annotations

import pytest

from lessmap.core import Partitioner, PartitionParams, Transition
from tests.core.helpers import Walk, observe_all, room_walk

SEEDS = range(6)


def segment(walk: Walk, profile: str = "laser") -> list[Transition]:
    return observe_all(Partitioner(PartitionParams.from_profile(profile)), walk.frames)


def share_in(features: tuple[int, ...], room: frozenset[int]) -> float:
    return len(room.intersection(features)) / len(features)


def assert_one_transition_per_door(walk: Walk, found: list[Transition], max_lag: int) -> None:
    seqs = [t.seq for t in found]
    assert len(found) == len(walk.doors), f"transitions at {seqs}, doors at {walk.doors}"
    for index, (transition, door) in enumerate(zip(found, walk.doors, strict=True)):
        assert door <= transition.seq <= door + max_lag, f"door {door}: detected at {seqs}"
        assert transition.boundary_seq <= transition.seq
        # The area left and the area entered are those rooms (door features aside).
        left, entered = walk.rooms[walk.route[index]], walk.rooms[walk.route[index + 1]]
        assert share_in(transition.closed.features, left) > 2 / 3
        assert share_in(transition.opened.features, entered) > 2 / 3
        assert transition.closed.frame_count >= 1


@pytest.mark.parametrize("back", [False, True], ids=["there", "there-and-back"])
@pytest.mark.parametrize("seed", SEEDS)
def test_each_door_gives_one_transition_soon_after(seed: int, back: bool) -> None:
    # A narrow door: one frame on each side sees about 10 % of the other room.
    walk = room_walk(seed, rooms=4, back=back, door_frames=1, door_share=0.1)
    found = segment(walk)
    assert_one_transition_per_door(walk, found, max_lag=5)
    for transition, door in zip(found, walk.doors, strict=True):
        assert abs(transition.boundary_seq - door) <= 1


@pytest.mark.parametrize("seed", SEEDS[:4])
def test_wide_doorway_delays_detection_but_not_the_boundary(seed: int) -> None:
    # Two frames on each side see 40 % of the other room. W_ij = a_ij / min(n_i, n_j) ties
    # each new-room feature to the old room's door features at about a_ij / n_new, which
    # fades only as the new room is seen more often; λ2 falls below 0.2 some 10 to 25
    # frames after the door. The boundary estimate still finds the door.
    walk = room_walk(seed, rooms=4, back=True, door_frames=2, door_share=0.4)
    found = segment(walk)
    assert_one_transition_per_door(walk, found, max_lag=28)
    for transition, door in zip(found, walk.doors, strict=True):
        assert abs(transition.boundary_seq - door) <= 2


@pytest.mark.parametrize("seed", SEEDS[:3])
def test_rooms_without_a_shared_view_disconnect_at_the_door(seed: int) -> None:
    walk = room_walk(seed, rooms=4, back=True, door_frames=0)
    found = segment(walk)
    assert [t.seq for t in found] == list(walk.doors)
    assert [t.boundary_seq for t in found] == list(walk.doors)
    assert all(t.reason == "DISCONNECTED" for t in found)
    for index, transition in enumerate(found):
        assert set(transition.opened.features) <= walk.rooms[walk.route[index + 1]]


@pytest.mark.parametrize("seed", SEEDS[:2])
def test_staying_in_one_room_gives_no_transition(seed: int) -> None:
    walk = room_walk(seed, rooms=1, stay=(200, 200))
    for profile in ("laser", "monocular"):
        assert segment(walk, profile) == []

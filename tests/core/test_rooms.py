"""The rooms method on streams whose rooms are known: a windowed cut, confirmed and named."""

from __future__ import annotations

import numpy as np
import pytest

from lessmap.core.errors import GraphError, StaleFrameError
from lessmap.core.rooms import snapshot
from lessmap.core.rooms.params import RoomParams
from lessmap.core.rooms.tracker import RoomTracker
from lessmap.core.rooms.window import FrameWindow
from tests.core.helpers import as_npz_snapshot

ROOM_M = 10.0  # rooms side by side along x: room k spans [10 k, 10 k + 10)
SPACING_M = 0.5  # wall landmarks, two walls a room
RANGE_M = 8.0


def landmarks(rooms: int) -> list[tuple[int, int, float]]:
    """(id, room, x) of every wall landmark; ids unique, two per spacing step."""
    found: list[tuple[int, int, float]] = []
    for room in range(rooms):
        for step in range(int(ROOM_M / SPACING_M)):
            x = room * ROOM_M + step * SPACING_M
            found += [(len(found), room, x), (len(found) + 1, room, x)]
    return found


def walk(
    xs: list[float], rooms: int = 3, seed: int = 0, detect: float = 0.9
) -> list[tuple[int, float, list[int]]]:
    """Frames of a robot at each x: its own room's landmarks in range, a glimpse at doors."""
    rng = np.random.default_rng(seed)
    marks = landmarks(rooms)
    frames = []
    for seq, x in enumerate(xs):
        room = min(int(x // ROOM_M), rooms - 1)
        seen = [
            i for i, r, lx in marks if abs(lx - x) <= RANGE_M and (r == room or abs(lx - x) < 1.0)
        ]
        kept = [i for i in seen if rng.random() < detect]
        frames.append((seq, seq / 10.0, kept))
    return frames


Change = tuple[int, int, int, int, int | None]  # seq, boundary, area, left area, revisit


def run(tracker: RoomTracker, frames: list[tuple[int, float, list[int]]]) -> list[Change]:
    changes = []
    for seq, stamp, features in frames:
        found = tracker.observe(seq, stamp, features)
        if found is not None:
            t = found.transition
            changes.append((t.seq, t.boundary_seq, found.area, found.left_area, found.revisit_of))
    return changes


def along(start: float, stop: float, step: float) -> list[float]:
    return [float(x) for x in np.arange(start, stop, step)]


def test_a_walk_through_a_door_is_one_change_at_the_door() -> None:
    xs = along(1.0, 19.0, 0.1)
    changes = run(RoomTracker(), walk(xs))
    assert len(changes) == 1
    seq, boundary, area, left, revisit = changes[0]
    assert abs(xs[boundary] - ROOM_M) <= 1.0  # the boundary within a metre of the door
    assert seq > boundary  # decided after the boundary, from the frames past it
    assert xs[seq] - xs[boundary] <= 1.5  # and soon: within 1.5 m
    assert (area, left) == (1, 0)
    assert revisit is None


def test_coming_back_enters_the_first_area_again() -> None:
    xs = along(1.0, 19.0, 0.1) + along(19.0, 1.0, -0.1)
    changes = run(RoomTracker(), walk(xs))
    assert [(area, left, revisit) for *_, area, left, revisit in changes] == [
        (1, 0, None),
        (0, 1, 0),
    ]


def test_standing_and_pacing_in_one_room_is_no_change() -> None:
    xs = along(2.0, 8.0, 0.1) + along(8.0, 2.0, -0.1) + [5.0] * 200
    assert run(RoomTracker(), walk(xs)) == []


def test_empty_frames_are_no_boundary() -> None:
    frames = walk(along(1.0, 9.0, 0.1))
    blind = [(seq, stamp, [] if 30 <= seq < 50 else f) for seq, stamp, f in frames]
    assert run(RoomTracker(), blind) == []


@pytest.mark.parametrize("step_m", [0.05, 0.1, 0.3, 0.5])
def test_the_door_is_found_at_any_speed_or_frame_rate(step_m: float) -> None:
    # The window is sized by how fast the view changes, not by a count of frames.
    xs = along(1.0, 29.0, step_m)
    changes = run(RoomTracker(), walk(xs, seed=3))
    doors = sorted(xs[boundary] for _, boundary, *_ in changes)
    assert len(doors) == 2
    assert abs(doors[0] - 10.0) <= 1.0
    assert abs(doors[1] - 20.0) <= 1.0


def test_the_window_learns_a_longer_half_at_a_slower_pace() -> None:
    widths = []
    for step_m in (0.1, 0.5):
        window = FrameWindow(RoomParams())
        for seq, _, features in walk(along(0.0, 29.0, step_m), seed=1):
            if features:
                window.add(seq, frozenset(features))
        widths.append(window.width())
    assert widths[0] is not None
    assert widths[1] is not None
    assert widths[0] > 2 * widths[1]


def test_the_window_reaches_as_far_whatever_the_detection_rate() -> None:
    # Missed detections lower every CovRate, not how far the view reaches: the window is
    # sized against the stream's own ceiling.
    def width(detect: float, *, relative: bool = True) -> int:
        # the old absolute bar: 0.6 of CovRate 1
        params = (
            RoomParams() if relative else RoomParams(window_similarity=0.6, window_relative=False)
        )
        window = FrameWindow(params)
        for seq, _, features in walk(along(0.0, 29.0, 0.3), seed=1, detect=detect):
            if features:
                window.add(seq, frozenset(features))
        found = window.width()
        assert found is not None
        return found

    sure, noisy = width(0.9), width(0.7)
    assert abs(sure - noisy) <= 0.2 * sure
    assert width(0.7, relative=False) < 0.7 * sure  # a bar of CovRate itself shrinks it


def test_a_session_saved_before_the_relative_window_keeps_its_window() -> None:
    tracker = RoomTracker(RoomParams(window_similarity=0.6, window_relative=False))
    run(tracker, walk(along(1.0, 19.0, 0.1), seed=2))
    data = snapshot.to_bytes(tracker)
    restored = snapshot.from_bytes(data)
    assert restored.params == tracker.params
    assert snapshot.to_bytes(restored) == data
    saved = {k: v for k, v in snapshot._hex(tracker.params).items() if k != "window_relative"}
    assert snapshot._params(saved) == tracker.params  # a field it did not have: off


def test_a_restored_tracker_goes_on_with_the_same_decisions_and_bytes() -> None:
    frames = walk(along(1.0, 29.0, 0.1) + along(29.0, 1.0, -0.1), seed=5)
    straight = RoomTracker()
    expected = run(straight, frames)
    resumed = RoomTracker()
    got: list[Change] = []
    for start in range(0, len(frames), 37):
        resumed = snapshot.from_bytes(snapshot.to_bytes(resumed))
        got += run(resumed, frames[start : start + 37])
    assert got == expected
    assert len(expected) >= 4
    assert snapshot.to_bytes(resumed) == snapshot.to_bytes(straight)


def test_damaged_bytes_are_one_error() -> None:
    with pytest.raises(GraphError, match="not a room snapshot"):
        snapshot.from_bytes(b"garbage")
    data = snapshot.to_bytes(RoomTracker())
    with pytest.raises(GraphError, match="room snapshot damaged"):
        snapshot.from_bytes(data[: len(data) // 2])


def test_a_version_1_snapshot_reads_as_the_same_tracker() -> None:
    """Records stored before the framing (an ``.npz`` archive) resume exactly."""
    tracker = RoomTracker()
    run(tracker, walk(along(1.0, 29.0, 0.1), seed=2))
    data = snapshot.to_bytes(tracker)
    old = as_npz_snapshot(data, snapshot, lambda meta: meta.update(version=1))
    assert old.startswith(b"PK")  # a zip archive, as version 1 was written
    assert snapshot.to_bytes(snapshot.from_bytes(old)) == data
    too_new = as_npz_snapshot(data, snapshot, lambda meta: meta.update(version=3))
    with pytest.raises(GraphError, match="version 3, expected 1 or 2"):
        snapshot.from_bytes(too_new)


def test_a_stale_frame_is_refused() -> None:
    tracker = RoomTracker()
    tracker.observe(5, 0.5, [1, 2])
    with pytest.raises(StaleFrameError, match="seq 5 is not after"):
        tracker.observe(5, 0.6, [1, 2])


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("window_similarity", 1.0),
        ("window_min_frames", 1),
        ("window_max_frames", 1),
        ("ahead_share", 0.0),
        ("cut_min", 0.0),
        ("known_share", 0.0),
        ("sure_cut", 0.0),
        ("sure_features", 0),
        ("min_side_features", 0),
        ("revisit_overlap", 1.5),
        ("max_area_sightings", -1),
    ],
)
def test_a_bad_parameter_is_named(field: str, value: float) -> None:
    with pytest.raises(GraphError, match=f"invalid room parameter {field}="):
        RoomParams(**{field: value})  # type: ignore[arg-type]


def test_area_models_stay_under_their_bound() -> None:
    xs = along(1.0, 59.0, 0.2)
    tracker = RoomTracker(RoomParams(max_area_sightings=60))
    run(tracker, walk(xs, rooms=6))
    assert tracker.sightings <= 60 + 2 * len(landmarks(1))  # the current area may exceed it
    assert tracker.area_count >= 5

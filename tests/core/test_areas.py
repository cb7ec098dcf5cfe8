"""AreaTracker: confirmed area changes, named revisits, no fragments, exact snapshots."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from lessmap.core import GraphError, PartitionParams, StaleFrameError
from lessmap.core.areas import snapshot
from lessmap.core.areas.snapshot import AREAS_SNAPSHOT_VERSION, from_bytes, to_bytes
from lessmap.core.areas.tracker import AreaParams, AreaTracker, AreaTransition
from tests.core.helpers import Frames, as_npz_snapshot, room_walk

if TYPE_CHECKING:
    from collections.abc import Callable


def track(
    frames: Frames, params: AreaParams | None = None, cuts: frozenset[int] = frozenset()
) -> tuple[AreaTracker, list[AreaTransition]]:
    """Observe frames (seq = index); before each seq in ``cuts`` restore from a snapshot."""
    tracker = AreaTracker(params)
    found: list[AreaTransition] = []
    for seq, frame in enumerate(frames):
        if seq in cuts:
            data = to_bytes(tracker)
            restored = from_bytes(data)
            assert to_bytes(restored) == data  # deterministic bytes
            tracker = restored
        change = tracker.observe(seq, seq * 0.1, frame)
        if change is not None:
            found.append(change)
    return tracker, found


@pytest.mark.parametrize("seed", range(4))
def test_a_walk_there_and_back_names_the_rooms_it_returns_to(seed: int) -> None:
    walk = room_walk(seed, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    tracker, found = track(walk.frames)
    assert [change.transition.boundary_seq for change in found] == pytest.approx(
        list(walk.doors), abs=2
    )
    areas = [0] + [change.area for change in found]
    # route 0 1 2 3 2 1 0: the way back re-enters the areas of the way out
    assert areas == [0, 1, 2, 3, 2, 1, 0]
    assert [change.revisit_of for change in found] == [None, None, None, 2, 1, 0]
    assert all(change.overlap >= 0.5 for change in found[3:])
    assert tracker.area_count == 4
    for change, room in zip(found, walk.route[1:], strict=True):
        assert set(change.transition.opened.features) & walk.rooms[room]
        assert len(change.transition.closed.features) >= 5


@pytest.mark.parametrize("seed", range(3))
def test_restore_mid_stream_gives_the_same_changes(seed: int) -> None:
    walk = room_walk(seed, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    rng = np.random.default_rng(seed)
    cuts = {int(c) for c in rng.choice(len(walk.frames), size=8, replace=False)}
    cuts |= {d + k for d in walk.doors for k in range(-1, 4)}  # pending proposals too
    expected = track(walk.frames)[1]
    assert len(expected) == 6
    assert track(walk.frames, cuts=frozenset(cuts))[1] == expected


def test_restore_keeps_params_and_areas() -> None:
    params = AreaParams(
        proposal=PartitionParams(ncut_min=0.3, lambda2_min=0.35, history_frames=50),
        pool_min_features=3,
        pool_max_frames=2,
        min_area_features=4,
        revisit_overlap=0.6,
        confirm_frames=5,
        history_frames=80,
    )
    walk = room_walk(1, rooms=3, back=True, stay=(20, 25))
    tracker, _ = track(walk.frames[:70], params)
    restored = from_bytes(to_bytes(tracker))
    assert restored.params == params
    assert restored.areas == tracker.areas
    assert restored.current_segment() == tracker.current_segment()
    assert (restored.last_seq, restored.transitions) == (tracker.last_seq, tracker.transitions)


def test_sparse_frames_never_close_a_fragment() -> None:
    """One or two of 15 landmarks per frame (an MRCLAM-like stream): no closed area < 5."""
    rng = np.random.default_rng(7)
    frames: Frames = [
        rng.choice(15, size=int(rng.integers(0, 3)), replace=False).tolist() for _ in range(3000)
    ]
    _, found = track(frames)
    assert all(len(change.transition.closed.features) >= 5 for change in found)
    assert all(len(change.transition.opened.features) >= 5 for change in found)


def test_pooling_feeds_the_proposer_fewer_frames() -> None:
    tracker, _ = track([[1], [2], [3], [4], [5], [6, 7, 8, 9, 10, 11], []])
    # pools: [1..4] (four features in four frames), [5, 6..11] (seven), one frame pending
    assert (tracker.params.pool_min_features, tracker.params.pool_max_frames) == (4, 4)
    assert tracker.proposer.frames_applied == 2
    assert tracker.pool.frames == 1
    wide, _ = track([[1], [2], [3], [4], [5]], AreaParams(pool_min_features=3, pool_max_frames=9))
    assert wide.proposer.frames_applied == 1  # [1, 2, 3] closed on features
    assert wide.pool.features == {4, 5}


def test_stale_and_malformed_frames_change_nothing() -> None:
    tracker = AreaTracker()
    tracker.observe(5, 0.5, [1, 2])
    with pytest.raises(StaleFrameError, match="seq 5"):
        tracker.observe(5, 0.6, [3])
    with pytest.raises(GraphError, match="integers"):
        tracker.observe(6, 0.6, [1.5])  # type: ignore[list-item]
    with pytest.raises(GraphError, match="integers"):
        tracker.observe(6, 0.6, [True])
    assert tracker.frames_applied == 1
    assert tracker.current_segment().features == (1, 2)


@pytest.mark.parametrize(
    "field", ["pool_min_features", "pool_max_frames", "min_area_features", "history_frames"]
)
def test_invalid_params_are_named(field: str) -> None:
    with pytest.raises(GraphError, match=field):
        AreaParams(**{field: 0})  # type: ignore[arg-type]


def test_garbage_and_other_versions_are_graph_errors() -> None:
    with pytest.raises(GraphError, match="not an area snapshot"):
        from_bytes(b"garbage")
    data = to_bytes(AreaTracker())
    assert AREAS_SNAPSHOT_VERSION == 11
    with pytest.raises(GraphError, match="area snapshot damaged"):
        from_bytes(data[: len(data) // 2])


def test_a_version_7_snapshot_resumes_under_the_default_bound() -> None:
    # Sessions checkpointed before rule 9 resume: version 7 had no max_area_sightings.
    tracker = AreaTracker(AreaParams(max_area_sightings=50))
    for seq in range(40):
        tracker.observe(seq, seq * 0.1, [seq % 12, (seq + 1) % 12, 100 + seq % 5])
    data = to_bytes(tracker)

    def as_version(version: int) -> Callable[[dict[str, Any]], None]:
        def edit(meta: dict[str, Any]) -> None:
            meta["version"] = version
            del meta["params"]["max_area_sightings"]

        return edit

    old = from_bytes(as_npz_snapshot(data, snapshot, as_version(7)))
    assert old.params == replace(tracker.params, max_area_sightings=100_000)
    assert old.sightings == tracker.sightings > 0
    with pytest.raises(GraphError, match="version 6, expected one of 7, 8, 9, 10, 11"):
        from_bytes(as_npz_snapshot(data, snapshot, as_version(6)))


def test_a_version_9_snapshot_reads_as_the_same_tracker() -> None:
    """Records stored before the framing (an ``.npz`` archive) resume exactly."""
    tracker = AreaTracker()
    for seq in range(60):
        tracker.observe(seq, seq * 0.1, [seq % 12, (seq + 1) % 12, 100 + seq % 5])
    data = to_bytes(tracker)
    old = as_npz_snapshot(data, snapshot, lambda meta: meta.update(version=9))
    assert old.startswith(b"PK")  # a zip archive, as version 9 was written
    assert to_bytes(from_bytes(old)) == data

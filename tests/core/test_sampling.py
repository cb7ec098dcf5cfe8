"""Feature sampling: a feature kept in every frame or in none, and sessions that stay exact."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from lessmap.core import GraphError
from lessmap.core.areas import snapshot
from lessmap.core.areas.sampling import KEEP_ALL, FeatureSampler, mix_ids
from lessmap.core.areas.snapshot import from_bytes, to_bytes
from lessmap.core.areas.tracker import AreaParams, AreaTracker
from lessmap.core.segmenter import make_segmenter, segmenter_from_bytes
from tests.core.helpers import Frames, as_npz_snapshot, room_walk
from tests.core.test_areas import track

SAMPLED = AreaParams(max_features_kept=64)


def camera_walk(seed: int) -> tuple[Frames, tuple[int, ...]]:
    """A room walk whose landmarks are each 20 features (a camera's texture): ~200-550 a frame."""
    walk = room_walk(seed, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    frames = [[f * 32 + k for f in frame for k in range(20)] for frame in walk.frames]
    return frames, walk.doors


def kept_ids(threshold: int, frame: tuple[int, ...]) -> tuple[int, ...]:
    """The ids of a frame whose mix is under the threshold (the rule, recomputed)."""
    mixed = mix_ids(np.asarray(frame, dtype=np.int64)).tolist()
    return tuple(f for f, h in zip(frame, mixed, strict=True) if h < threshold)


def test_the_mix_is_splitmix64_on_every_run() -> None:
    # Reference values of splitmix64's finalizer (Steele, Lea, Flood 2014) for 0, 1 and -1.
    ids = np.array([0, 1, -1], dtype=np.int64)
    assert mix_ids(ids).tolist() == [0xE220A8397B1DCDAF, 0x910A2DEC89025CC1, 0xE4D971771B652C20]


@pytest.mark.parametrize("seed", range(4))
def test_a_feature_is_kept_in_every_frame_or_in_none(seed: int) -> None:
    rng = np.random.default_rng(seed)
    sampler = FeatureSampler(100)
    pool = rng.choice(10**9, size=5000, replace=False) - 5 * 10**8
    frames = [
        tuple(sorted(rng.choice(pool, size=int(rng.integers(50, 1200)), replace=False).tolist()))
        for _ in range(60)
    ]
    thresholds, kept = [], []
    for frame in frames:
        kept.append(sampler.keep(frame))
        thresholds.append(sampler.threshold)
    assert thresholds == sorted(thresholds, reverse=True)  # it only falls
    assert all(len(k) <= 100 for k in kept)
    final = thresholds[-1]
    assert 0 < final < KEEP_ALL
    for frame, threshold, found in zip(frames, thresholds, kept, strict=True):
        assert found == kept_ids(threshold, frame)  # the same rule in every frame
        assert set(kept_ids(final, frame)) <= set(found)  # nested: kept now, kept before
    # once the threshold settles, every frame keeps exactly the ids under it
    after = FeatureSampler(100, final)
    for frame in frames:
        assert after.keep(frame) == kept_ids(final, frame)
    assert after.threshold == final


def test_the_same_frames_make_the_same_choices() -> None:
    rng = np.random.default_rng(3)
    frames = [tuple(sorted(set(rng.integers(0, 10**6, size=900).tolist()))) for _ in range(20)]
    first, second = FeatureSampler(128), FeatureSampler(128)
    assert [first.keep(f) for f in frames] == [second.keep(f) for f in frames]
    assert first.threshold == second.threshold < KEEP_ALL
    assert 0.0 < first.rate < 1.0


def test_frames_under_the_cap_are_kept_whole() -> None:
    sampler = FeatureSampler(8)
    frame = (1, 5, 9, 200, 3000)
    assert sampler.keep(frame) is frame
    assert sampler.threshold == KEEP_ALL
    assert FeatureSampler(0).keep(tuple(range(10_000))) == tuple(range(10_000))  # 0: off


@pytest.mark.parametrize(("cap", "threshold"), [(-1, KEEP_ALL), (4, -1), (4, KEEP_ALL + 1)])
def test_bad_sampler_state_is_named(cap: int, threshold: int) -> None:
    with pytest.raises(GraphError, match="feature sample"):
        FeatureSampler(cap, threshold)


def test_an_area_parameter_names_a_negative_cap() -> None:
    with pytest.raises(GraphError, match="max_features_kept"):
        AreaParams(max_features_kept=-1)


@pytest.mark.parametrize("seed", [0, 1, 3])  # seed 2's walk splits a room even unsampled
def test_a_sampled_session_finds_the_doors(seed: int) -> None:
    frames, doors = camera_walk(seed)
    tracker, found = track(frames, SAMPLED)
    assert tracker.sampler.rate < 0.5
    assert max(len(features) for _, features in tracker.frames) <= 64
    assert [c.transition.boundary_seq for c in found] == pytest.approx(list(doors), abs=3)
    assert [c.revisit_of for c in found] == [None, None, None, 2, 1, 0]
    # the CovGraph holds kept ids only: the full graph's induced subgraph
    threshold = tracker.sampler.threshold
    nodes = [f for f in {f for frame in frames for f in frame} if tracker.proposer.graph.count(f)]
    assert nodes
    assert kept_ids(threshold, tuple(nodes)) == tuple(nodes)


def test_a_sampled_session_decides_as_the_whole_one() -> None:
    frames, _ = camera_walk(0)
    _, found = track(frames, SAMPLED)
    _, whole = track(frames, replace(SAMPLED, max_features_kept=0))
    assert [c.transition.boundary_seq for c in found] == pytest.approx(
        [c.transition.boundary_seq for c in whole], abs=1
    )
    assert [(c.area, c.revisit_of) for c in found] == [(c.area, c.revisit_of) for c in whole]


@pytest.mark.parametrize("seed", range(2))
def test_restore_mid_stream_keeps_the_same_samples_and_changes(seed: int) -> None:
    frames, doors = camera_walk(seed)
    rng = np.random.default_rng(seed)
    cuts = {int(c) for c in rng.choice(len(frames), size=8, replace=False)} | {1, 2}
    cuts |= {d + k for d in doors for k in range(-1, 3)}
    expected_tracker, expected = track(frames, SAMPLED)
    restored_tracker, restored = track(frames, SAMPLED, frozenset(cuts))
    assert restored == expected
    assert restored_tracker.sampler.threshold == expected_tracker.sampler.threshold
    assert to_bytes(restored_tracker) == to_bytes(expected_tracker)


def test_a_segmenter_restored_from_bytes_decides_as_the_original() -> None:
    frames, _ = camera_walk(4)
    params = replace(AreaParams(), max_features_kept=64)
    original = make_segmenter("areas", area_params=params)
    restored = None
    changes: tuple[list[object], list[object]] = ([], [])
    for seq, frame in enumerate(frames):
        if seq == len(frames) // 3:
            restored = segmenter_from_bytes(original.to_bytes())
        for index, segmenter in enumerate((original, restored)):
            if segmenter is not None:
                segmenter.apply(seq, seq * 0.1, frame)
                found = segmenter.decide()
                if seq >= len(frames) // 3:
                    changes[index].extend(c.area for c in found)
    assert restored is not None
    assert changes[0] == changes[1]
    assert restored.to_bytes() == original.to_bytes()
    assert restored.max_features_kept == 64


def test_a_stream_under_the_cap_is_decided_as_without_sampling() -> None:
    walk = room_walk(2, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    _, sampled = track(walk.frames, AreaParams())
    _, whole = track(walk.frames, AreaParams(max_features_kept=0))
    assert sampled == whole
    assert len(sampled) == 6


def test_a_version_8_snapshot_resumes_keeping_every_feature() -> None:
    tracker = AreaTracker(AreaParams(max_features_kept=0))
    for seq in range(30):
        tracker.observe(seq, seq * 0.1, list(range(seq, seq + 12)))

    def as_version_8(meta: dict[str, Any]) -> None:
        meta["version"] = 8
        del meta["params"]["max_features_kept"], meta["sample_threshold"]

    old = from_bytes(as_npz_snapshot(to_bytes(tracker), snapshot, as_version_8))
    assert old.params.max_features_kept == 0
    assert old.sampler.threshold == KEEP_ALL
    old.observe(30, 3.0, list(range(1000, 3000)))  # far over the default cap: all kept
    assert len(old.frames[-1][1]) == 2000
    assert old.proposer.graph.count(2999) or old.pool.features >= {2999}


def test_paper_keeps_every_feature() -> None:
    segmenter = make_segmenter("paper", area_params=AreaParams(max_features_kept=8))
    assert segmenter.max_features_kept == 0
    segmenter.apply(0, 0.0, list(range(1000)))
    segmenter.decide()
    assert segmenter.node_count == 1000

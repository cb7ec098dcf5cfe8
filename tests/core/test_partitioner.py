"""The partitioner of one session: transitions, guards, seed modes, coalescing, params."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from lessmap.core import (
    GraphError,
    Partitioner,
    PartitionParams,
    Reason,
    SeedMode,
    StaleFrameError,
    Submap,
    Transition,
)
from lessmap.core.paper.partitioner import _feature_ids
from tests.core.helpers import (
    TWO_ROOM_DOOR,
    assert_same_state,
    brute_counts,
    observe_all,
    room_walk,
    two_room_frames,
)

if TYPE_CHECKING:
    from collections.abc import Iterable

    from tests.core.helpers import Frames


def test_two_rooms_give_one_spectral_transition() -> None:
    frames = two_room_frames()
    partitioner = Partitioner(PartitionParams.from_profile("laser"))
    [transition] = observe_all(partitioner, frames)

    assert transition.reason is Reason.SPECTRAL
    assert transition.closed.features == tuple(range(10))
    assert transition.opened.features == tuple(range(10, 20))
    assert transition.boundary_seq <= transition.seq
    assert abs(transition.boundary_seq - TWO_ROOM_DOOR) <= 2
    assert TWO_ROOM_DOOR <= transition.seq <= TWO_ROOM_DOOR + 5
    assert transition.ncut is not None
    assert transition.lambda2 is not None
    assert 0.0 <= transition.lambda2 <= transition.ncut <= 0.25
    assert transition.lambda2 <= 0.2
    assert transition.stamp_s == float(transition.seq)
    assert transition.batch_frames == 1
    # Frames split at the boundary: the closed submap ends just before it.
    assert transition.closed == Submap(
        id=0,
        first_seq=0,
        last_seq=transition.boundary_seq - 1,
        frame_count=transition.boundary_seq,
        features=tuple(range(10)),
    )
    assert transition.opened.id == 1
    assert transition.opened.first_seq == transition.boundary_seq
    assert transition.opened.last_seq == transition.seq
    assert transition.opened.frame_count == transition.seq - transition.boundary_seq + 1
    # Cut edges join the door features of both rooms.
    assert set(transition.boundary_features) <= set(range(5, 20))
    assert {5, 10} <= set(transition.boundary_features)
    # The submap bookkeeping agrees with the transition.
    assert partitioner.closed_submaps == (transition.closed,)
    assert partitioner.transitions == 1
    assert partitioner.frames_applied == len(frames)
    current = partitioner.current_submap()
    assert (current.id, current.first_seq, current.last_seq) == (1, transition.boundary_seq, 61)
    assert current.frame_count == 62 - transition.boundary_seq
    assert current.features == tuple(range(10, 20))


def test_evaluation_reports_each_decision() -> None:
    partitioner = Partitioner()
    partitioner.observe(0, 0.0, [1])
    assert partitioner.last_evaluation is not None
    assert partitioner.last_evaluation.nodes == 1
    assert partitioner.last_evaluation.ncut is None
    partitioner.observe(1, 1.0, [1, 2, 3])
    evaluation = partitioner.last_evaluation
    assert evaluation is not None
    assert (evaluation.seq, evaluation.nodes, evaluation.components) == (1, 3, 1)
    # K_3 has λ2 = 1.5 > λ2_min: proven without the eigen-solve, so no figures.
    assert (evaluation.ncut, evaluation.lambda2) == (None, None)
    assert evaluation.lambda2_above == partitioner.params.lambda2_min
    assert evaluation.transition is False


def test_always_solve_reports_the_figures_of_each_decision() -> None:
    partitioner = Partitioner(always_solve=True)
    partitioner.observe(0, 0.0, [1])
    partitioner.observe(1, 1.0, [1, 2, 3])
    evaluation = partitioner.last_evaluation
    assert evaluation is not None
    assert evaluation.lambda2 == pytest.approx(1.5)  # K_3: λ2 = n / (n - 1)
    assert evaluation.ncut is not None
    assert evaluation.lambda2_above is None


def test_disconnected_graph_is_a_transition_without_figures() -> None:
    partitioner = Partitioner()
    assert partitioner.observe(0, 0.5, [1, 2, 3]) is None
    transition = partitioner.observe(1, 1.5, [7, 8, 9])
    assert transition == Transition(
        seq=1,
        boundary_seq=1,
        stamp_s=1.5,
        reason=Reason.DISCONNECTED,
        ncut=None,
        lambda2=None,
        closed=Submap(id=0, first_seq=0, last_seq=0, frame_count=1, features=(1, 2, 3)),
        opened=Submap(id=1, first_seq=1, last_seq=1, frame_count=1, features=(7, 8, 9)),
        boundary_features=(),
        batch_frames=1,
    )
    assert partitioner.last_evaluation is not None
    assert partitioner.last_evaluation.components == 2
    assert partitioner.graph.feature_ids.tolist() == [7, 8, 9]


@pytest.mark.parametrize(
    ("door", "boundary"),
    [([0, 1, 2, 3, 10, 11, 12, 13, 14], 30), ([0, 1, 2, 3, 4, 10, 11, 12, 13, 14], 32)],
    ids=["door mostly new", "door exactly half"],
)
def test_boundary_is_the_first_frame_of_the_trailing_majority_run(
    door: list[int], boundary: int
) -> None:
    # seq 30 is the door, 31 and 33 are empty: an empty frame neither breaks nor starts the
    # run of frames that lie mostly (> half) in the new cluster.
    room = list(range(10, 20))
    frames: Frames = [list(range(10)) for _ in range(30)]
    frames += [door, [], room, [], room, room, room]
    [transition] = transitions_of(frames)
    assert transition.seq == 32
    assert transition.boundary_seq == boundary
    assert transition.closed.last_seq == boundary - 1
    assert transition.closed.frame_count == boundary
    assert transition.opened.frame_count == 33 - boundary
    assert transition.closed.features == tuple(range(10))


def walk_frames(seed: int) -> Frames:
    return room_walk(seed, rooms=3, stay=(25, 35)).frames


def transitions_of(frames: Frames, params: PartitionParams | None = None) -> list[Transition]:
    return observe_all(Partitioner(params), frames)


def mapped(submap: Submap, mapping: dict[int, int]) -> Submap:
    return replace(submap, features=tuple(sorted(mapping[f] for f in submap.features)))


@pytest.mark.parametrize("seed", range(3))
def test_relabelling_feature_ids_changes_nothing_but_the_ids(seed: int) -> None:
    frames = walk_frames(seed)
    ids = sorted({f for frame in frames for f in frame})
    rng = np.random.default_rng(seed)
    targets = rng.choice(2**62, size=len(ids), replace=False) - 2**61  # injective, any order
    mapping = dict(zip(ids, targets.tolist(), strict=True))
    original = transitions_of(frames)
    relabelled = transitions_of([[mapping[f] for f in frame] for frame in frames])

    assert len(original) >= 2
    assert len(relabelled) == len(original)
    for a, b in zip(original, relabelled, strict=True):
        assert (b.seq, b.boundary_seq, b.reason, b.batch_frames) == (
            a.seq,
            a.boundary_seq,
            a.reason,
            a.batch_frames,
        )
        assert a.ncut is not None
        assert a.lambda2 is not None
        assert b.ncut == pytest.approx(a.ncut, abs=1e-9)
        assert b.lambda2 == pytest.approx(a.lambda2, abs=1e-9)
        assert b.closed == mapped(a.closed, mapping)
        assert b.opened == mapped(a.opened, mapping)
        assert b.boundary_features == tuple(sorted(mapping[f] for f in a.boundary_features))


@given(seed=st.integers(0, 2**32 - 1), duplicate=st.booleans())
@settings(max_examples=5, deadline=None)
def test_order_and_repeats_inside_frames_change_nothing(seed: int, duplicate: bool) -> None:
    frames = walk_frames(seed % 7)
    rng = np.random.default_rng(seed)
    shuffled = []
    for frame in frames:
        again = frame + frame[: len(frame) // 2] if duplicate else list(frame)
        shuffled.append([int(f) for f in rng.permutation(np.array(again, dtype=np.int64))])
    assert transitions_of(shuffled) == transitions_of(frames)


def test_stale_frames_are_rejected_and_change_nothing() -> None:
    partitioner = Partitioner()
    observe_all(partitioner, two_room_frames()[:20])
    partitioner.apply(20, 20.0, [1, 2])  # a pending, undecided frame is state too
    before = partitioner.state()
    for seq in (20, 19, 0, -1):
        with pytest.raises(StaleFrameError, match=f"frame seq {seq} is not after"):
            partitioner.apply(seq, 99.0, [1, 42])
        with pytest.raises(StaleFrameError):
            partitioner.observe(seq, 99.0, [1, 42])
    assert_same_state(partitioner.state(), before)
    assert partitioner.last_seq == 20
    assert partitioner.pending_frames == 1
    assert partitioner.graph.count(42) == 0


@pytest.mark.parametrize(
    "features", [["a"], [None], [2**63], [1.5], ["7"]], ids=["str", "None", "2**63", "1.5", "'7'"]
)
def test_feature_ids_must_be_int64(features: list[Any]) -> None:
    # Docstring of Partitioner.apply: GraphError when a feature ID is not an integer in the
    # int64 range; nothing changes.
    partitioner = Partitioner()
    partitioner.observe(0, 0.0, [1, 2])
    before = partitioner.state()
    with pytest.raises(GraphError, match="feature IDs must be integers"):
        partitioner.apply(1, 1.0, [3, *features])
    assert_same_state(partitioner.state(), before)


CHAIN: Frames = [[3 * k + 1, 3 * k + 2, 3 * k + 3] for k in range(12)]  # each frame alone


@pytest.mark.parametrize("guard", [0, 1, 2, 4])
def test_min_frames_between_skips_the_test_after_each_transition(guard: int) -> None:
    found = transitions_of(CHAIN, PartitionParams(min_frames_between=guard))
    # The first `guard` frames of the session and of every new submap are not tested.
    assert [t.seq for t in found] == list(range(max(guard, 1), len(CHAIN), guard + 1))
    assert all(t.reason is Reason.DISCONNECTED for t in found)
    for t in found:  # the current frame's component opens; everything else closes
        assert t.opened.features == tuple(CHAIN[t.seq])


def test_min_frames_between_delays_a_spectral_transition() -> None:
    found = transitions_of(two_room_frames(), PartitionParams(min_frames_between=40))
    assert [t.seq for t in found] == [40]
    assert found[0].closed.features == tuple(range(10))


@pytest.mark.parametrize("size", [1, 3, 4])
def test_min_cluster_size_suppresses_small_cuts(size: int) -> None:
    partitioner = Partitioner(PartitionParams(min_cluster_size=size))
    found = observe_all(partitioner, [[1, 2, 3], [7, 8, 9, 10], [7, 8, 9, 10]])
    evaluation = partitioner.last_evaluation
    assert evaluation is not None
    if size <= 3:
        assert [t.seq for t in found] == [1]
        assert found[0].closed.features == (1, 2, 3)
    else:
        assert found == []
        assert evaluation.components == 2
        assert evaluation.transition is False
        assert partitioner.graph.node_count == 7  # nothing was dropped


def test_min_cluster_size_above_a_room_suppresses_the_spectral_transition() -> None:
    assert transitions_of(two_room_frames(), PartitionParams(min_cluster_size=10)) != []
    assert transitions_of(two_room_frames(), PartitionParams(min_cluster_size=11)) == []


@pytest.mark.parametrize("mode", list(SeedMode))
def test_graph_after_a_transition_per_seed_mode(mode: SeedMode) -> None:
    frames = two_room_frames()
    partitioner = Partitioner(PartitionParams(seed_mode=mode))
    transition = None
    for seq, frame in enumerate(frames):  # stop right at the transition
        transition = partitioner.observe(seq, float(seq), frame)
        if transition is not None:
            break
    assert transition is not None
    graph = partitioner.graph
    opened = list(transition.opened.features)
    if mode is SeedMode.SEED:
        nodes, pairs = brute_counts(frames[: transition.seq + 1])
        assert graph.feature_ids.tolist() == sorted(opened)
        assert graph.counts.tolist() == [nodes[f] for f in opened]
        assert graph.edge_count == 45  # all pairs of 10..19 met, nothing else kept
        for a in opened:
            assert graph.pair_count(a, 9) == 0
            for b in opened:
                assert graph.pair_count(a, b) == (pairs[frozenset((a, b))] if a != b else 0)
        assert partitioner.current_submap().features == tuple(opened)
    else:
        assert graph.node_count == 0
        assert partitioner.current_submap().features == ()
        partitioner.observe(100, 100.0, [10, 11, 30])
        assert partitioner.graph.counts.tolist() == [1, 1, 1]
    assert partitioner.closed_submaps == (transition.closed,)


@pytest.mark.parametrize("mode", list(SeedMode))
@pytest.mark.parametrize("seed", range(2))
def test_both_seed_modes_find_every_room_of_a_walk(mode: SeedMode, seed: int) -> None:
    walk = room_walk(seed, rooms=3)
    found = transitions_of(walk.frames, PartitionParams(seed_mode=mode))
    assert len(found) == len(walk.doors)
    for transition, door in zip(found, walk.doors, strict=True):
        assert door <= transition.seq <= door + 8


@pytest.mark.parametrize("k", [1, 2, 3, 5, 7])
def test_coalesced_decisions_cover_the_batch_and_still_find_the_room(k: int) -> None:
    frames = two_room_frames()
    partitioner = Partitioner()
    found: list[Transition] = []
    for seq, frame in enumerate(frames):
        partitioner.apply(seq, float(seq), frame)
        assert partitioner.pending_frames == seq % k + 1
        if (seq + 1) % k == 0:
            transition = partitioner.decide()
            assert partitioner.pending_frames == 0
            if transition is not None:
                found.append(transition)
    [transition] = found
    assert transition.batch_frames == k
    assert (transition.seq + 1) % k == 0  # detected at a decision, covering its batch
    assert transition.closed.features == tuple(range(10))
    assert transition.opened.features == tuple(range(10, 20))
    assert abs(transition.boundary_seq - TWO_ROOM_DOOR) <= 2
    assert TWO_ROOM_DOOR <= transition.seq <= TWO_ROOM_DOOR + 5 + k


def test_coalesced_disconnection_reports_the_batch() -> None:
    partitioner = Partitioner()
    partitioner.apply(0, 0.0, [1, 2, 3])
    partitioner.apply(1, 1.0, [])
    partitioner.apply(2, 2.0, [7, 8, 9])
    transition = partitioner.decide()
    assert transition is not None
    assert (transition.seq, transition.batch_frames, transition.reason) == (
        2,
        3,
        Reason.DISCONNECTED,
    )
    assert partitioner.decide() is None  # nothing pending


def test_decisions_over_empty_frames_change_nothing() -> None:
    partitioner = Partitioner()
    assert partitioner.decide() is None
    partitioner.observe(0, 0.0, [1, 2, 3])
    evaluation = partitioner.last_evaluation
    for seq in (1, 2):
        assert partitioner.observe(seq, float(seq), []) is None
    assert partitioner.last_evaluation is evaluation
    assert partitioner.current_submap().frame_count == 3


def test_empty_frames_between_frames_keep_the_decisions() -> None:
    frames = two_room_frames()
    padded: Frames = []
    for frame in frames:
        padded += [frame, []]
    [plain] = transitions_of(frames)
    [spaced] = transitions_of(padded)
    assert spaced.seq == 2 * plain.seq
    assert (spaced.ncut, spaced.lambda2) == (plain.ncut, plain.lambda2)
    assert spaced.closed.features == plain.closed.features
    assert spaced.opened.features == plain.opened.features


@pytest.mark.parametrize(
    ("profile", "thresholds"),
    [("laser", (0.25, 0.2)), ("stereo", (0.25, 0.2)), ("monocular", (0.1, 0.1))],
)
def test_profiles_are_the_papers_thresholds(profile: str, thresholds: tuple[float, float]) -> None:
    params = PartitionParams.from_profile(profile)
    assert (params.ncut_min, params.lambda2_min) == thresholds
    assert params.seed_mode is SeedMode.SEED


def test_profile_overrides() -> None:
    params = PartitionParams.from_profile("monocular", lambda2_min=0.05, seed_mode="fresh")
    assert (params.ncut_min, params.lambda2_min, params.seed_mode) == (0.1, 0.05, SeedMode.FRESH)
    assert PartitionParams() == PartitionParams.from_profile("laser")


def test_unknown_profile_is_a_graph_error() -> None:
    with pytest.raises(GraphError, match="unknown profile 'sonar'"):
        PartitionParams.from_profile("sonar")


@pytest.mark.parametrize(
    "bad",
    [
        {"ncut_min": -0.01},
        {"lambda2_min": -1.0},
        {"min_frames_between": -1},
        {"min_cluster_size": 0},
        {"dense_max_nodes": 1},
        {"history_frames": 0},
        {"keep_closed_submaps": -1},
    ],
    ids=lambda bad: next(iter(bad)),
)
def test_invalid_params_are_graph_errors(bad: dict[str, Any]) -> None:
    name = next(iter(bad))
    with pytest.raises(GraphError, match=f"invalid partition parameter {name}="):
        PartitionParams(**bad)
    with pytest.raises(GraphError, match=name):
        PartitionParams.from_profile("laser", **bad)


def test_unknown_seed_mode_is_rejected() -> None:
    with pytest.raises(ValueError, match="'sometimes' is not a valid SeedMode"):
        PartitionParams(seed_mode="sometimes")  # type: ignore[arg-type]


def test_tight_thresholds_find_nothing_loose_ones_more() -> None:
    frames = two_room_frames()
    assert transitions_of(frames, PartitionParams(ncut_min=0.0, lambda2_min=0.0)) == []
    loose = transitions_of(frames, PartitionParams(ncut_min=0.5, lambda2_min=0.35))
    [paper] = transitions_of(frames)
    assert loose[0].seq < paper.seq
    # The early cut leaves door features with the new room; a later one closes them.
    closed = [f for t in loose for f in t.closed.features]
    assert sorted(closed) == list(range(10))


def test_keep_closed_submaps_and_history_bounds() -> None:
    partitioner = Partitioner(PartitionParams(keep_closed_submaps=2, history_frames=3))
    found = observe_all(partitioner, CHAIN)
    assert len(found) == len(CHAIN) - 1
    assert partitioner.closed_submaps == tuple(t.closed for t in found[-2:])
    assert partitioner.transitions == len(found)
    assert [t.closed.id for t in found] == list(range(len(found)))


@given(
    st.lists(
        st.one_of(
            st.integers(-(2**64), 2**64),
            st.integers(-5, 5),
            st.booleans(),
            st.floats(allow_nan=False, width=32),
        ),
        max_size=30,
    )
)
def test_a_list_of_ints_gives_the_array_numpy_would(features: list[Any]) -> None:
    # The plain-list shortcut of _feature_ids against the numpy path (a tuple takes it):
    # the same distinct sorted IDs, as ints and as int64, or the same error.
    def outcome(values: Iterable[Any]) -> tuple[str, Any]:
        try:
            ids, array = _feature_ids(7, values)
            assert array.dtype == np.int64
            return "ok", (ids, array.tolist())
        except GraphError as exc:
            return "error", str(exc)

    assert outcome(features) == outcome(tuple(features))

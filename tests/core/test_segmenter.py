"""Segmenters: the wrapped method's decisions exactly, and whole-state bytes that continue them."""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from lessmap.core import GraphError, Partitioner, PartitionParams, StaleFrameError
from lessmap.core.areas.graph import MAX_BOUNDARY_FEATURES, AreaGraph, AreaGraphBuilder
from lessmap.core.areas.tracker import AreaParams, AreaTracker, AreaTransition
from lessmap.core.paper import snapshot
from lessmap.core.paper.submaps import Transition
from lessmap.core.rooms.params import RoomParams
from lessmap.core.segmenter import (
    AreasSegmenter,
    Method,
    PaperSegmenter,
    RoomsSegmenter,
    SegmentChange,
    Segmenter,
    make_segmenter,
    segmenter_from_bytes,
)
from lessmap.core.segmenter_snapshot import MAGIC, pack
from lessmap.files.frames import read_frames
from lessmap.sim.simulator import simulate
from tests.conftest import dataset
from tests.core.helpers import room_walk, two_room_frames

if TYPE_CHECKING:
    from collections.abc import Callable

Frame = tuple[int, float, list[int]]
V1_FIXTURE = Path(__file__).parent / "data" / "snapshot_v1.npz"


@cache
def sim_frames(
    seed: int, fov_deg: float = 270.0, room_size_m: tuple[float, float] = (4.0, 8.0)
) -> tuple[Frame, ...]:
    """One robot walking a simulated building of four rooms (it comes back to some)."""
    run = simulate(
        seed, rooms=4, robots=1, frames_per_robot=300, fov_deg=fov_deg, room_size_m=room_size_m
    )
    return tuple((f["seq"], f["stamp"], list(f["features"])) for f in run.frames)


@cache
def mrclam6_frames() -> tuple[Frame, ...]:
    """Robot 3 of MRCLAM dataset 6: one or two of 15 landmarks a frame, gaps in its seqs."""
    rows = read_frames(dataset("mrclam6.frames.jsonl"))
    return tuple((r.seq, r.stamp_s, list(r.features)) for r in rows if r.robot == "3")


def walk_frames(seed: int) -> tuple[Frame, ...]:
    walk = room_walk(seed, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    return tuple((seq, seq * 0.1, frame) for seq, frame in enumerate(walk.frames))


STREAMS: dict[str, Callable[[], tuple[Frame, ...]]] = {
    "sim 270": lambda: sim_frames(0),
    "sim 360": lambda: sim_frames(1, 360.0),
    "open rooms": lambda: sim_frames(0, room_size_m=(8.0, 10.0)),  # areas merge here
    "mrclam6": mrclam6_frames,
}


def batches(n: int, size: int) -> list[int]:
    """Frames per decision: ``size`` each, or 1-9 at random (seeded) when ``size`` is 0."""
    if size:
        return [size] * (n // size) + ([n % size] if n % size else [])
    rng = np.random.default_rng(n)
    sizes: list[int] = []
    while sum(sizes) < n:
        sizes.append(min(int(rng.integers(1, 10)), n - sum(sizes)))
    return sizes


@dataclass
class Run:
    """What a segmenter reported over a stream, and what its restores saw."""

    changes: list[SegmentChange] = field(default_factory=list)
    restored_with_pending_frames: int = 0
    restored_with_held_changes: int = 0


def drive(
    segmenter: Segmenter, frames: tuple[Frame, ...], size: int, cuts: frozenset[int] = frozenset()
) -> tuple[Segmenter, Run]:
    """Apply frames in batches, deciding after each; before frame ``i`` in ``cuts``, restore."""
    run = Run()
    index = 0
    for batch in batches(len(frames), size):
        for seq, stamp, features in frames[index : index + batch]:
            if index in cuts:
                data = segmenter.to_bytes()
                restored = segmenter_from_bytes(data)
                assert restored.to_bytes() == data  # deterministic bytes
                run.restored_with_pending_frames += segmenter.pending_frames > 0
                run.restored_with_held_changes += segmenter.transitions > len(run.changes)
                segmenter = restored
            segmenter.apply(seq, stamp, features)
            index += 1
        run.changes += segmenter.decide()
    return segmenter, run


def paper_reference(frames: tuple[Frame, ...], size: int) -> list[Transition]:
    """A bare partitioner, making the calls a coalescing service makes."""
    partitioner = Partitioner()
    found: list[Transition] = []
    index = 0
    for batch in batches(len(frames), size):
        for seq, stamp, features in frames[index : index + batch]:
            partitioner.apply(seq, stamp, features)
        index += batch
        transition = partitioner.decide()
        if transition is not None:
            found.append(transition)
    return found


def areas_reference(
    frames: tuple[Frame, ...], size: int = 1, params: AreaParams | None = None
) -> tuple[list[AreaTransition], AreaGraph]:
    """A bare tracker settled after each batch (``observe`` per frame), and its area graph."""
    tracker, builder = AreaTracker(params), AreaGraphBuilder()
    found: list[AreaTransition] = []
    index = 0
    for batch in batches(len(frames), size):
        if batch == 1:
            seq, stamp, features = frames[index]
            change = tracker.observe(seq, stamp, features)
        else:
            for seq, stamp, features in frames[index : index + batch]:
                tracker.add(seq, stamp, features)
            change = tracker.settle()
        index += batch
        if change is not None:
            found.append(change)
            builder.add(change)
    return found, builder.graph(tracker)


def summary(segmenter: Segmenter) -> tuple[object, ...]:
    """Everything a segmenter reports besides its changes."""
    return (
        segmenter.method,
        segmenter.last_seq,
        segmenter.frames_applied,
        segmenter.transitions,
        segmenter.pending_frames,
        segmenter.current_area,
        segmenter.node_count,
        segmenter.edge_count,
        segmenter.current_submap(),
        tuple(segmenter.closed_submaps),
        segmenter.area_graph(),
    )


# -- 1, 2: the wrapped method's decisions ---------------------------------------------------


@pytest.mark.parametrize("size", [1, 4, 0], ids=["per frame", "by 4", "random bursts"])
@pytest.mark.parametrize("stream", STREAMS)
def test_paper_changes_are_the_partitioners_transitions(stream: str, size: int) -> None:
    frames = STREAMS[stream]()
    expected = paper_reference(frames, size)
    segmenter, run = drive(make_segmenter(Method.PAPER), frames, size)
    assert [change.transition for change in run.changes] == expected
    assert len(expected) >= 3
    for change in run.changes:
        t = change.transition
        assert (change.area, change.left_area, change.revisit_of) == (
            t.opened.id,
            t.closed.id,
            None,
        )
        assert change.reason == t.reason.value
    assert segmenter.transitions == len(expected) == segmenter.current_area
    if size != 1:
        assert any(t.batch_frames > 1 for t in expected)  # coalescing did happen


@pytest.mark.parametrize("size", [1, 5], ids=["per frame", "by 5"])
@pytest.mark.parametrize("stream", STREAMS)
def test_areas_changes_are_the_trackers(stream: str, size: int) -> None:
    frames = STREAMS[stream]()
    # MRCLAM's frames are its robots' sightings: it leaves out its empty frames
    params = AreaParams().for_stream(empty_frames_omitted=stream == "mrclam6")
    expected, graph = areas_reference(frames, size, params)
    segmenter, run = drive(make_segmenter("areas", area_params=params), frames, size)
    assert [(c.transition, c.area, c.left_area, c.revisit_of, c.reason) for c in run.changes] == [
        (c.transition, c.area, c.left_area, c.revisit_of, c.reason.value) for c in expected
    ]
    assert segmenter.area_graph() == graph
    # mrclam6's robot 3 is in one arena: its turns between the walls, blind for seconds
    # (stamp gaps), are no transition (rule 3b); the other streams change area
    assert len(expected) == 0 if stream == "mrclam6" else len(expected) >= 3
    assert segmenter.closed_submaps == tuple(c.transition.closed for c in expected)
    assert segmenter.current_area == (expected[-1].area if expected else 0)


def test_the_streams_exercise_revisits_recognition_and_merges() -> None:
    """What the areas method adds to the paper's is in the streams the tests above run."""
    found, _ = areas_reference(sim_frames(0))
    assert any(c.revisit_of is not None for c in found)
    assert "RECOGNISED" in {c.reason.value for c in found}
    tracker = AreaTracker()
    for frame in STREAMS["open rooms"]():
        tracker.observe(*frame)
    assert tracker.merged  # an area graph resolves ids that a past change named


def test_areas_size_is_the_proposers_graph() -> None:
    segmenter = AreasSegmenter()
    for seq, stamp, features in sim_frames(0)[:40]:
        segmenter.apply(seq, stamp, features)
    graph = segmenter.tracker.proposer.graph
    assert (segmenter.node_count, segmenter.edge_count) == (graph.node_count, graph.edge_count)
    assert segmenter.node_count > 0
    known = graph.feature_ids.tolist()
    assert all(segmenter.feature_known(f) for f in known)
    assert not segmenter.feature_known(max(known) + 1)


# -- 3: whole state in bytes ----------------------------------------------------------------


def cuts_for(frames: tuple[Frame, ...], method: Method) -> frozenset[int]:
    """Eight seeded cuts, and the frames just after each change is found (held changes)."""
    rng = np.random.default_rng(len(frames))
    cuts = {int(c) for c in rng.choice(len(frames), size=8, replace=False)}
    segmenter = make_segmenter(method)
    for index, (seq, stamp, features) in enumerate(frames):
        before = segmenter.transitions
        segmenter.apply(seq, stamp, features)
        if method is Method.PAPER:
            segmenter.decide()
        if segmenter.transitions > before:
            cuts |= {index + 1, index + 2}
    return frozenset(c for c in cuts if c < len(frames))


@pytest.mark.parametrize("method", list(Method))
@pytest.mark.parametrize("stream", STREAMS)
def test_restored_mid_stream_goes_on_exactly(method: Method, stream: str) -> None:
    frames = STREAMS[stream]()
    cuts = cuts_for(frames, method)
    straight, expected = drive(make_segmenter(method), frames, 3)
    resumed, run = drive(make_segmenter(method), frames, 3, cuts)
    assert run.changes == expected.changes
    assert summary(resumed) == summary(straight)
    assert resumed.to_bytes() == straight.to_bytes()
    # Restored between frames not yet decided: for the areas method, frames whose tests wait
    # for ``decide`` (its changes are found there, so none is ever held across a restore);
    # the rooms method finds its changes at ``apply``, so some are held across one.
    assert run.restored_with_pending_frames > 0
    if method is Method.ROOMS:
        assert run.restored_with_held_changes > 0
    else:
        assert run.restored_with_held_changes == 0


@pytest.mark.parametrize("method", list(Method))
def test_a_restore_before_the_first_frame_and_after_the_last(method: Method) -> None:
    fresh = segmenter_from_bytes(make_segmenter(method).to_bytes())
    assert summary(fresh) == summary(make_segmenter(method))
    segmenter, _ = drive(make_segmenter(method), walk_frames(2)[:90], 2)
    segmenter.apply(90, 9.0, [])  # a pending empty frame
    restored = segmenter_from_bytes(segmenter.to_bytes())
    assert summary(restored) == summary(segmenter)
    assert restored.decide() == segmenter.decide()


@pytest.mark.parametrize("method", list(Method))
def test_parameters_survive_the_bytes(method: Method) -> None:
    params = PartitionParams(ncut_min=0.3, lambda2_min=0.3, keep_closed_submaps=2)
    segmenter = make_segmenter(method, params)
    restored = segmenter_from_bytes(segmenter.to_bytes())
    assert isinstance(restored, type(segmenter))
    if isinstance(restored, PaperSegmenter):
        assert restored.partitioner.params == params
    elif isinstance(restored, RoomsSegmenter):
        assert isinstance(segmenter, RoomsSegmenter)
        assert restored.tracker.params == segmenter.tracker.params
    else:
        assert isinstance(restored, AreasSegmenter)
        assert isinstance(segmenter, AreasSegmenter)
        assert restored.tracker.params == segmenter.tracker.params


def test_room_parameters_survive_the_bytes() -> None:
    params = RoomParams(window_similarity=0.65, cut_min=0.2, known_share=0.85)
    segmenter = make_segmenter(Method.ROOMS, room_params=params)
    restored = segmenter_from_bytes(segmenter.to_bytes())
    assert isinstance(restored, RoomsSegmenter)
    assert restored.tracker.params == params


# -- 4: checkpoints written before segmenters ------------------------------------------------


def test_a_bare_partitioner_snapshot_reads_as_a_paper_segmenter() -> None:
    frames = walk_frames(0)
    partitioner = Partitioner()
    before = [t for seq, stamp, f in frames[:70] if (t := partitioner.observe(seq, stamp, f))]
    partitioner.apply(*frames[70])  # one frame pending, as a checkpoint may hold
    segmenter = segmenter_from_bytes(snapshot.to_bytes(partitioner))
    assert isinstance(segmenter, PaperSegmenter)
    assert segmenter.pending_frames == 1
    rest = frames[71:]
    expected = [partitioner.decide()] + [partitioner.observe(*frame) for frame in rest]
    found = [segmenter.decide()]
    for frame in rest:
        segmenter.apply(*frame)
        found.append(segmenter.decide())
    assert [change.transition for changes in found for change in changes] == [
        t for t in expected if t is not None
    ]
    graph = segmenter.area_graph()
    old = {t.closed.id for t in before}
    assert old
    assert len(graph.edges) > len(old)
    for edge in graph.edges:
        assert bool(edge.boundary_features) != (edge.a in old)  # old passages: none known


def test_a_version_1_partitioner_snapshot_still_reads() -> None:
    # tests/core/data/snapshot_v1.npz: a room walk's first 71 frames, odd seqs decided
    segmenter = segmenter_from_bytes(V1_FIXTURE.read_bytes())
    assert isinstance(segmenter, PaperSegmenter)
    assert (segmenter.last_seq, segmenter.frames_applied, segmenter.pending_frames) == (70, 71, 1)


# -- 5: damaged bytes -------------------------------------------------------------------------


def framed(rest: bytes) -> bytes:
    """The magic and a valid CRC around anything."""
    return MAGIC + struct.pack("<I", zlib.crc32(rest)) + rest


def reframed(header: object, body: bytes = b"") -> bytes:
    """A record with a valid CRC around any header: only the reading of it can fail."""
    encoded = header if isinstance(header, bytes) else json.dumps(header).encode()
    return framed(struct.pack("<I", len(encoded)) + encoded + body)


@cache
def good(method: Method) -> bytes:
    segmenter, _ = drive(make_segmenter(method), walk_frames(1), 1)
    return segmenter.to_bytes()


def flipped(data: bytes, at: int) -> bytes:
    return data[:at] + bytes([data[at] ^ 0x40]) + data[at + 1 :]


def header(method: str = "paper", **meta: object) -> dict[str, object]:
    return {"version": 1, "method": method, "meta": meta, "sections": [["inner", 0]]}


DAMAGED: dict[str, Callable[[], bytes]] = {
    "empty": lambda: b"",
    "garbage": lambda: b"garbage bytes, not a snapshot",
    "magic only": lambda: MAGIC,
    "magic and a CRC": lambda: MAGIC + b"\0\0\0\0\1",
    "paper truncated": lambda: good(Method.PAPER)[:-9],
    "areas truncated": lambda: good(Method.AREAS)[: len(good(Method.AREAS)) // 2],
    "paper bit flipped": lambda: flipped(good(Method.PAPER), 40),
    "areas bit flipped": lambda: flipped(good(Method.AREAS), len(good(Method.AREAS)) - 30),
    "CRC mismatch": lambda: MAGIC + b"\0" * 4 + b"\xff" * 8,
    "header not json": lambda: reframed(b'{"version": 1,'),
    "header not UTF-8": lambda: reframed(b"\xff{}"),
    "header length beyond the record": lambda: framed(struct.pack("<I", 99) + b"{}"),
    "header a list": lambda: reframed([1, 2]),
    "version 9": lambda: reframed({**header(), "version": 9}),
    "unknown method": lambda: reframed(header("magic")),
    "no sections": lambda: reframed({"version": 1, "method": "paper", "meta": {}}),
    "section too long": lambda: reframed({**header(), "sections": [["inner", 99]]}, b"abc"),
    "section malformed": lambda: reframed({**header(), "sections": [["inner"]]}),
    "paper without its meta": lambda: reframed(header()),
    "paper inner garbage": lambda: reframed(header(boundaries=[])),
    "areas inner garbage": lambda: reframed(
        header("areas", pending_frames=0, builder={}, closed=[], held=[])
    ),
    "areas meta of the wrong types": lambda: pack("areas", {"pending_frames": "many"}, b"", {}),
    "partitioner snapshot truncated": lambda: snapshot.to_bytes(Partitioner())[:30],
    "npz garbage": lambda: b"PK\x03\x04 not really a zip",
}


@pytest.mark.parametrize("make", DAMAGED.values(), ids=DAMAGED.keys())
def test_damaged_bytes_are_one_clear_graph_error(make: Callable[[], bytes]) -> None:
    with pytest.raises(GraphError) as caught:
        segmenter_from_bytes(make())
    message = str(caught.value)
    assert message
    assert "\n" not in message
    assert "snapshot" in message or "version" in message


def test_unknown_method_is_refused() -> None:
    with pytest.raises(GraphError, match="unknown segmentation method 'spectral'"):
        make_segmenter("spectral")


# -- apply's errors ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", list(Method))
@pytest.mark.parametrize(
    ("seq", "features", "error"),
    [
        (4, [1], StaleFrameError),
        (3, [1.5], StaleFrameError),  # stale first, as the partitioner checks
        (5, [1.5], GraphError),
        (5, [True], GraphError),
        (5, ["7"], GraphError),
        (5, [2**63], GraphError),  # the tracker alone takes it, and fails pools later
        (5, np.array([2**64 - 1], dtype=np.uint64), GraphError),
    ],
)
def test_refused_frames_are_the_partitioners_and_change_nothing(
    method: Method, seq: int, features: object, error: type[Exception]
) -> None:
    segmenter, partitioner = make_segmenter(method), Partitioner()
    for s in range(5):
        segmenter.apply(s, s * 0.1, [1, 2, 3, s + 10])
        partitioner.apply(s, s * 0.1, [1, 2, 3, s + 10])
    before = segmenter.to_bytes()
    with pytest.raises(error) as expected:
        partitioner.apply(seq, 1.0, features)  # type: ignore[arg-type]
    with pytest.raises(error) as found:
        segmenter.apply(seq, 1.0, features)  # type: ignore[arg-type]
    assert type(found.value) is type(expected.value)
    assert str(found.value) == str(expected.value)
    assert segmenter.to_bytes() == before
    for s in range(5, 12):  # and it goes on
        segmenter.apply(s, s * 0.1, [1, 2, 3, s + 10])
    assert segmenter.frames_applied == 12


# -- 6: the paper's area graph ----------------------------------------------------------------


def test_paper_area_graph_is_one_area_per_segment() -> None:
    segmenter = PaperSegmenter()
    changes: list[SegmentChange] = []
    for seq, frame in enumerate(two_room_frames()):
        segmenter.apply(seq, seq * 0.1, frame)
        changes += segmenter.decide()
    (change,) = changes
    closed, current = change.transition.closed, segmenter.current_submap()
    graph = segmenter.area_graph()
    assert [
        (n.area, n.frames, n.visits, n.first_seq, n.last_seq, n.features) for n in graph.nodes
    ] == [(s.id, s.frame_count, 1, s.first_seq, s.last_seq, s.features) for s in (closed, current)]
    (edge,) = graph.edges
    assert (edge.a, edge.b, edge.a_to_b, edge.b_to_a) == (0, 1, 1, 0)
    boundary = change.transition.boundary_features
    assert boundary
    assert edge.boundary_features == tuple((f, 1) for f in boundary[:MAX_BOUNDARY_FEATURES])


def test_paper_area_graph_trims_like_an_area_graph_and_keeps_what_the_partitioner_keeps() -> None:
    segmenter = make_segmenter(Method.PAPER, PartitionParams(keep_closed_submaps=3))
    changes: list[SegmentChange] = []
    for seq, stamp, features in sim_frames(1, 360.0):
        segmenter.apply(seq, stamp, features)
        changes += segmenter.decide()
    assert len(changes) > 3
    graph = segmenter.area_graph()
    assert segmenter_from_bytes(segmenter.to_bytes()).area_graph() == graph
    assert [n.area for n in graph.nodes] == list(range(len(changes) - 3, len(changes) + 1))
    assert [(e.a, e.b) for e in graph.edges] == [(n.area, n.area + 1) for n in graph.nodes[:-1]]
    # equal counts: an area graph keeps the smallest ids (its ties), MAX_BOUNDARY_FEATURES
    for edge, change in zip(graph.edges, changes[-3:], strict=True):
        boundary = sorted(change.transition.boundary_features)
        assert edge.boundary_features == tuple((f, 1) for f in boundary[:MAX_BOUNDARY_FEATURES])
    assert any(len(c.transition.boundary_features) > MAX_BOUNDARY_FEATURES for c in changes[-3:])


@pytest.mark.parametrize("stream", ["sim 270"])
def test_areas_tests_run_once_per_decision_when_frames_are_coalesced(
    stream: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Under load the service decides once for several frames: so do the area tests."""
    frames = STREAMS[stream]()
    calls: list[int] = []
    settle = AreaTracker.settle

    def counted(tracker: AreaTracker) -> AreaTransition | None:
        calls.append(tracker.last_seq or 0)
        return settle(tracker)

    monkeypatch.setattr(AreaTracker, "settle", counted)
    drive(make_segmenter("areas"), frames, 5)
    assert len(calls) == len(batches(len(frames), 5))
    assert len(calls) < len(frames) / 4

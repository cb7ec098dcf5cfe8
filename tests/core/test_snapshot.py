"""Snapshots: bytes -> partitioner -> the same decisions as never stopping."""

from __future__ import annotations

import io
import json
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lessmap.core import GraphError, Partitioner, PartitionParams, SeedMode, Transition
from lessmap.core.paper import covgraph
from lessmap.core.paper.snapshot import SNAPSHOT_VERSION, from_bytes, to_bytes
from tests.core.helpers import assert_same_state, observe_all, room_walk, two_room_frames
from tests.core.test_dense_path import dense_frames

V1_FIXTURE = Path(__file__).parent / "data" / "snapshot_v1.npz"

PARAMS = [
    PartitionParams(),
    PartitionParams(seed_mode=SeedMode.FRESH, min_frames_between=3, min_cluster_size=2),
    PartitionParams(history_frames=7, keep_closed_submaps=1, dense_max_nodes=2),
]


def run_with_restores(
    frames: list[list[int]], params: PartitionParams, cuts: set[int], batch: int = 1
) -> list[Transition]:
    """Apply frames, deciding every ``batch`` frames; before frame c in ``cuts`` replace the
    partitioner by its restored snapshot (possibly with undecided frames pending)."""
    partitioner = Partitioner(params)
    found: list[Transition] = []
    for seq, frame in enumerate(frames):
        if seq in cuts:
            data = to_bytes(partitioner)
            restored = from_bytes(data)
            assert_same_state(restored.state(), partitioner.state())
            assert to_bytes(restored) == data  # deterministic bytes
            partitioner = restored
        partitioner.apply(seq, seq * 0.1, frame)  # stamps that are not exact in binary
        if (seq + 1) % batch == 0:
            transition = partitioner.decide()
            if transition is not None:
                found.append(transition)
    return found


@pytest.mark.parametrize("params", PARAMS, ids=["default", "fresh-guarded", "small-arpack"])
@pytest.mark.parametrize("seed", range(3))
def test_restore_then_continue_gives_the_same_transitions(
    seed: int, params: PartitionParams
) -> None:
    walk = room_walk(seed, rooms=4, back=seed == 0, stay=(20, 30), door_frames=2, door_share=0.2)
    rng = np.random.default_rng(seed)
    cuts = {int(c) for c in rng.choice(len(walk.frames), size=6, replace=False)}
    cuts |= {d + k for d in walk.doors[:2] for k in range(4)}  # around decisions too
    batch = 1 + seed  # also with undecided frames in the snapshot
    expected = run_with_restores(walk.frames, params, set(), batch)
    assert len(expected) >= 2
    assert run_with_restores(walk.frames, params, cuts, batch) == expected


def test_restore_keeps_params_counters_and_submaps() -> None:
    params = PartitionParams.from_profile(
        "monocular", seed_mode="fresh", min_frames_between=1, history_frames=50
    )
    partitioner = Partitioner(params)
    found = observe_all(partitioner, two_room_frames()[:45])
    partitioner.apply(45, 45.0, [10, 11])
    restored = from_bytes(to_bytes(partitioner))
    assert restored.params == params
    assert restored.closed_submaps == tuple(t.closed for t in found)
    assert restored.current_submap() == partitioner.current_submap()
    assert (restored.last_seq, restored.pending_frames, restored.transitions) == (45, 1, len(found))
    assert restored.frames_applied == 46


def test_fresh_partitioner_round_trips() -> None:
    restored = from_bytes(to_bytes(Partitioner()))
    assert restored.last_seq is None
    assert restored.graph.node_count == 0
    assert observe_all(restored, two_room_frames()) == observe_all(Partitioner(), two_room_frames())


def snapshot_parts() -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(meta, arrays) of a version-2 snapshot, to build damaged ones from."""
    partitioner = Partitioner()
    observe_all(partitioner, two_room_frames()[:40])
    data = to_bytes(partitioner)
    assert data[:8] == b"LMSNAP2\n"
    (length,) = struct.unpack_from("<I", data, 12)
    header = json.loads(data[16 : 16 + length])
    blobs = data[16 + length :]
    arrays = {
        name: np.frombuffer(blobs[offset : offset + size], dtype=kind).reshape(shape)
        for name, kind, shape, offset, size in header["arrays"]
    }
    return header["meta"], arrays


def container(meta: object, arrays: dict[str, Any], *, table: object = None) -> bytes:
    """A version-2 snapshot of these parts with a correct CRC (so the content is judged);
    ``table`` replaces the header's array table."""
    blobs, entries, offset = [], [], 0
    for name, array in arrays.items():
        blob = array.tobytes()
        entries.append([name, array.dtype.str, list(array.shape), offset, len(blob)])
        blobs.append(blob)
        offset += len(blob)
    header = json.dumps({"meta": meta, "arrays": entries if table is None else table}).encode()
    rest = struct.pack("<I", len(header)) + header + b"".join(blobs)
    return b"LMSNAP2\n" + struct.pack("<I", zlib.crc32(rest)) + rest


def with_meta(**changes: object) -> bytes:
    meta, arrays = snapshot_parts()
    meta.update(changes)
    return container(meta, arrays)


def without(name: str) -> bytes:
    meta, arrays = snapshot_parts()
    del arrays[name]
    return container(meta, arrays)


def replaced(name: str, value: np.ndarray) -> bytes:
    meta, arrays = snapshot_parts()
    arrays[name] = value
    return container(meta, arrays)


def with_entry(name: str, entry: list[object]) -> bytes:
    meta, arrays = snapshot_parts()
    kept = [e for e in json.loads(container(meta, arrays)[16:].split(b"]]}")[0] + b"]]}")["arrays"]]
    return container(meta, arrays, table=[e if e[0] != name else entry for e in kept])


def flipped_body_byte() -> bytes:
    data = bytearray(to_bytes(Partitioner()))
    data[-5] ^= 0xFF
    return bytes(data)


GARBAGE = {
    "empty": b"",
    "text": b"not a snapshot",
    "random": np.random.default_rng(0).bytes(512),
    "magic only": b"LMSNAP2\n",
    "truncated": to_bytes(Partitioner())[:-40],
    "flipped data byte": flipped_body_byte(),  # the CRC catches it
    "header not an object": b"LMSNAP2\n"
    + struct.pack("<I", zlib.crc32(b"\x06\x00\x00\x00[1, 2]"))
    + b"\x06\x00\x00\x00[1, 2]",
    "meta a list": container([1, 2], snapshot_parts()[1]),
    "no counts": without("counts"),
    "future version": with_meta(version=SNAPSHOT_VERSION + 1),
    "no version": with_meta(version=None),
    "bad param": with_meta(params={"ncut_min": -1.0}),
    "unknown param": with_meta(params={"speed": 3}),
    "bad seed mode": with_meta(params={"seed_mode": "sometimes"}),
    "short counts": replaced("counts", np.zeros(3, dtype=np.int64)),
    "repeated ids": replaced("feature_ids", np.zeros(20, dtype=np.int64)),
    "indptr reversed": replaced("edge_indptr", snapshot_parts()[1]["edge_indptr"][::-1].copy()),
    "edge index out of range": replaced("edge_indices", snapshot_parts()[1]["edge_indices"] + 99),
    "short history seqs": replaced("history_seqs", np.zeros(1, dtype=np.int64)),
    "float counts": replaced("counts", snapshot_parts()[1]["counts"].astype(np.float64)),
    "object dtype": with_entry("counts", ["counts", "|O", [1], 0, 8]),
    "bytes short of the shape": with_entry("counts", ["counts", "<i8", [4], 0, 8]),
    "negative shape": with_entry("counts", ["counts", "<i8", [-1], 0, 0]),
    "beyond the end": with_entry("counts", ["counts", "<i8", [4], 10**9, 32]),
}


def v1_npz(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def v1_arrays() -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(V1_FIXTURE.read_bytes()), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def v1_with_meta(**changes: object) -> bytes:
    arrays = v1_arrays()
    meta = json.loads(arrays["meta"].tobytes().decode())
    meta.update(changes)
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    return v1_npz(arrays)


def pickled_object_array() -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    data = io.BytesIO()
    with zipfile.ZipFile(data, "w") as archive:
        archive.writestr("meta.npy", buffer.getvalue())
    return data.getvalue()


def v1_flipped(locate: bytes, offset: int) -> bytes:
    data = bytearray(V1_FIXTURE.read_bytes())
    data[data.index(locate) + offset] ^= 0xFF
    return bytes(data)


# Version 1 (npz) is still read: a record stored before the upgrade resumes.
V1_GARBAGE = {
    "v1 flipped data byte": v1_flipped(b'"version"', 3),  # the zip CRC catches it
    "v1 unknown compression": v1_flipped(b"PK\x01\x02", 10),
    "v1 zip of nothing": v1_npz({}),
    "v1 meta not json": v1_npz({**v1_arrays(), "meta": np.frombuffer(b"\xff{", np.uint8)}),
    "v1 meta a list": v1_npz({**v1_arrays(), "meta": np.frombuffer(b"[1, 2]", np.uint8)}),
    "v1 claims version 2": v1_with_meta(version=2),
    "v1 pickled object": pickled_object_array(),
}
GARBAGE.update(V1_GARBAGE)


def test_a_version_1_snapshot_resumes_with_the_same_state_and_decisions() -> None:
    # tests/core/data/snapshot_v1.npz: written by version 1 after these frames (odd seqs
    # decided, so one frame pending).
    walk = room_walk(0, rooms=4, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    live = Partitioner(PartitionParams())
    for seq, frame in enumerate(walk.frames[:71]):
        live.apply(seq, seq * 0.1, frame)
        if seq % 2:
            live.decide()
    restored = from_bytes(V1_FIXTURE.read_bytes())
    assert_same_state(restored.state(), live.state())
    assert from_bytes(to_bytes(restored)).state().last_stamp_s == 7.0
    rest = list(enumerate(walk.frames))[71:]
    assert observe_pairs(restored, rest) == observe_pairs(live, rest)


def observe_pairs(partitioner: Partitioner, frames: list[tuple[int, list[int]]]) -> list[object]:
    return [partitioner.observe(seq, seq * 0.1, frame) for seq, frame in frames]


@pytest.mark.parametrize("data", GARBAGE.values(), ids=GARBAGE.keys())
def test_garbage_is_a_graph_error(data: bytes) -> None:
    with pytest.raises(GraphError):
        from_bytes(data)


@pytest.mark.parametrize("seed", range(3))
def test_a_dense_graph_above_dense_max_nodes_restores_into_the_store_its_state_implies(
    seed: int,
) -> None:
    frames = dense_frames(seed, pool=60, seen=30, frames=90)
    params = PartitionParams(dense_max_nodes=20)  # ARPACK above 20 nodes
    rng = np.random.default_rng(seed)
    cuts = {int(c) for c in rng.choice(len(frames), size=8, replace=False)} | {44, 45, 46}
    expected = run_with_restores(frames, params, set())
    assert expected
    assert run_with_restores(frames, params, cuts) == expected
    partitioner = Partitioner(params)
    for seq, frame in enumerate(frames[:30]):
        partitioner.observe(seq, float(seq), frame)
    graph = from_bytes(to_bytes(partitioner)).graph
    n, edges = graph.node_count, graph.edge_count
    assert n > 20
    assert graph.dense_store == (200 * edges >= covgraph.DENSE_ENTER_PERCENT * n * (n - 1))
    assert graph.dense_store  # this stream: most pairs are edges

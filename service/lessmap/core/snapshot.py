"""A partitioner's whole state as bytes and back, bit-exact.

Format (version 2): the 8-byte magic ``LMSNAP2`` + newline, the CRC-32 of the body (4 bytes,
little-endian), then the body, one msgpack map: ``meta`` (the scalars, msgpack-native: floats
are IEEE doubles, so exact) and ``arrays`` (name -> [dtype, shape, raw little-endian bytes]).
msgpack is the wire contract's codec, so any client language reads it; the CRC catches a
damaged record, as the zip archive's did. Version 1, an uncompressed NumPy ``.npz`` archive
with a JSON ``meta`` entry, is still read (records stored before an upgrade), never written:
building a zip archive cost ~3 ms a checkpoint, as much as 40 frames' counting, on the
worker that decides for every robot of the shard (docs/BENCHMARKS.md).
"""

from __future__ import annotations

import io
import json
import struct
import zlib
from dataclasses import asdict
from itertools import chain
from typing import Any

import msgpack
import numpy as np

from lessmap.core.covgraph import CovGraphState
from lessmap.core.errors import GraphError
from lessmap.core.params import PartitionParams
from lessmap.core.partitioner import FrameRecord, Partitioner, PartitionerState
from lessmap.core.submaps import Submap

SNAPSHOT_VERSION = 2
_MAGIC = b"LMSNAP2\n"
_CRC = struct.Struct("<I")
_DTYPES = {"<i8": np.int64, "<f8": np.float64}  # the only ones a snapshot holds
_ARRAYS = (
    "feature_ids",
    "counts",
    "first_seen",
    "edge_indptr",
    "edge_indices",
    "edge_counts",
    "history_offsets",
    "history_values",
    "closed_offsets",
    "closed_values",
)


def _ragged(rows: list[list[int]] | list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Pack a list of int lists as (offsets, values)."""
    lengths = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
    offsets = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    values = np.concatenate(rows).astype(np.int64, copy=False) if rows else np.zeros(0, np.int64)
    return offsets, values


def _ragged_tuples(rows: list[tuple[int, ...]]) -> tuple[np.ndarray, np.ndarray]:
    """``_ragged`` for rows of Python ints (one pass, no array per row)."""
    lengths = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
    offsets = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    values = np.fromiter(chain.from_iterable(rows), dtype=np.int64, count=int(offsets[-1]))
    return offsets, values


def _unragged(offsets: np.ndarray, values: np.ndarray) -> list[np.ndarray]:
    return [values[offsets[i] : offsets[i + 1]] for i in range(offsets.size - 1)]


def to_bytes(partitioner: Partitioner) -> bytes:
    """Serialize a partitioner's whole state (format: module docstring)."""
    state = partitioner.state()
    history_offsets, history_values = _ragged([r.features for r in state.history])
    closed_offsets, closed_values = _ragged_tuples([s.features for s in state.closed_submaps])
    meta: dict[str, Any] = {
        "version": SNAPSHOT_VERSION,
        "params": {k: str(v) if k == "seed_mode" else v for k, v in asdict(state.params).items()},
        "history_seqs": [r.seq for r in state.history],
        "closed": [[s.id, s.first_seq, s.last_seq, s.frame_count] for s in state.closed_submaps],
        "submap_id": state.submap_id,
        "submap_first_seq": state.submap_first_seq,
        "submap_frame_count": state.submap_frame_count,
        "last_seq": state.last_seq,
        "last_stamp_s": state.last_stamp_s,
        "last_features": list(state.last_features),
        "pending_frames": state.pending_frames,
        "pending_nonempty": state.pending_nonempty,
        "frames_since_transition": state.frames_since_transition,
        "frames_applied": state.frames_applied,
        "transitions": state.transitions,
    }
    graph = state.graph
    arrays = {
        "feature_ids": graph.feature_ids,
        "counts": graph.counts,
        "first_seen": graph.first_seen,
        "edge_indptr": graph.edge_indptr,
        "edge_indices": graph.edge_indices,
        "edge_counts": graph.edge_counts,
        "history_offsets": history_offsets,
        "history_values": history_values,
        "closed_offsets": closed_offsets,
        "closed_values": closed_values,
    }
    body: bytes = msgpack.packb(
        {"meta": meta, "arrays": {name: _packed(a) for name, a in arrays.items()}},
        use_bin_type=True,
    )
    return _MAGIC + _CRC.pack(zlib.crc32(body)) + body


def _packed(array: np.ndarray) -> list[Any]:
    """[dtype, shape, bytes] of an int64 or float64 array, little-endian."""
    kind = "<f8" if array.dtype.kind == "f" else "<i8"
    data = np.ascontiguousarray(array, dtype=kind)
    return [kind, list(data.shape), data.tobytes()]


def _unpacked(name: str, entry: Any) -> np.ndarray:
    """The array of a ``_packed`` entry, checked against its declared dtype and shape."""
    kind, shape, data = entry
    dtype = _DTYPES.get(kind)
    if dtype is None or not isinstance(shape, list) or not isinstance(data, bytes):
        msg = f"array {name!r}: unsupported entry"
        raise GraphError(msg)
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if count < 0 or count * 8 != len(data):
        msg = f"array {name!r}: {len(data)} bytes for shape {shape}"
        raise GraphError(msg)
    return np.frombuffer(data, dtype=dtype).reshape(shape).copy()


def _read_v2(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    head = len(_MAGIC) + _CRC.size
    if len(data) < head:
        msg = "snapshot truncated"
        raise GraphError(msg)
    (crc,) = _CRC.unpack_from(data, len(_MAGIC))
    body = memoryview(data)[head:]
    if zlib.crc32(body) != crc:
        msg = "snapshot damaged: CRC-32 mismatch"
        raise GraphError(msg)
    doc = msgpack.unpackb(body, raw=False, strict_map_key=True)
    meta, packed = doc["meta"], doc["arrays"]
    if not isinstance(meta, dict) or not isinstance(packed, dict):
        msg = "snapshot body is not {meta, arrays}"
        raise GraphError(msg)
    return meta, {name: _unpacked(name, packed[name]) for name in _ARRAYS}


def _read_v1(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """A version-1 snapshot (npz, JSON meta; the stamp as a float hex string)."""
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        arrays = {name: archive[name] for name in archive.files}
    meta = json.loads(arrays.pop("meta").tobytes().decode())
    if not isinstance(meta, dict):
        msg = "snapshot meta is not a JSON object"
        raise GraphError(msg)
    if meta.get("version") != 1:
        msg = f"snapshot version {meta.get('version')!r}, expected 1 or {SNAPSHOT_VERSION}"
        raise GraphError(msg)
    meta["last_stamp_s"] = float.fromhex(meta["last_stamp_s"])
    return meta, arrays


def from_bytes(data: bytes) -> Partitioner:
    """Rebuild a partitioner from ``to_bytes`` output.

    Raises:
        GraphError: the bytes are not a snapshot of a supported version.
    """
    try:
        meta, arrays = _read_v2(data) if data.startswith(_MAGIC) else _read_v1(data)
        if meta.get("version") not in (1, SNAPSHOT_VERSION):
            msg = f"snapshot version {meta.get('version')!r}, expected {SNAPSHOT_VERSION}"
            raise GraphError(msg)
        params = PartitionParams(**meta["params"])
        history = tuple(
            FrameRecord(seq, features)
            for seq, features in zip(
                meta["history_seqs"],
                _unragged(arrays["history_offsets"], arrays["history_values"]),
                strict=True,
            )
        )
        closed = tuple(
            Submap(id=i, first_seq=f, last_seq=la, frame_count=c, features=tuple(feats.tolist()))
            for (i, f, la, c), feats in zip(
                meta["closed"],
                _unragged(arrays["closed_offsets"], arrays["closed_values"]),
                strict=True,
            )
        )
        state = PartitionerState(
            params=params,
            graph=CovGraphState(
                feature_ids=arrays["feature_ids"],
                counts=arrays["counts"],
                first_seen=arrays["first_seen"],
                edge_indptr=arrays["edge_indptr"],
                edge_indices=arrays["edge_indices"],
                edge_counts=arrays["edge_counts"],
            ),
            history=history,
            closed_submaps=closed,
            submap_id=meta["submap_id"],
            submap_first_seq=meta["submap_first_seq"],
            submap_frame_count=meta["submap_frame_count"],
            last_seq=meta["last_seq"],
            last_stamp_s=float(meta["last_stamp_s"]),
            last_features=tuple(meta["last_features"]),
            pending_frames=meta["pending_frames"],
            pending_nonempty=meta["pending_nonempty"],
            frames_since_transition=meta["frames_since_transition"],
            frames_applied=meta["frames_applied"],
            transitions=meta["transitions"],
        )
        return Partitioner.from_state(state)
    except GraphError:
        raise
    except Exception as exc:
        # Snapshot bytes come from storage or another instance: anything malformed, however
        # msgpack, numpy, zipfile or json report it, is one error type for the caller.
        msg = f"not a partitioner snapshot: {type(exc).__name__}: {exc}"
        raise GraphError(msg) from exc

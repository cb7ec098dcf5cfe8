"""A partitioner's whole state as bytes and back, bit-exact.

Format (version 2): the 8-byte magic ``LMSNAP2`` + newline, the CRC-32 of the rest (4 bytes,
little-endian), the length of the header (4 bytes, little-endian), the header (UTF-8 JSON:
``meta``, the scalars, and ``arrays``, a list of [name, dtype, shape, offset, bytes]), then
the arrays' raw bytes (int64, little-endian). Readable from any language with JSON and a
CRC; the CRC catches a damaged record, as the zip archive's did; the standard library only
(the core imports no codec). Version 1, an uncompressed NumPy ``.npz`` archive with a JSON
``meta`` entry, is still read (records stored before an upgrade), never written (why:
``docs/decisions/0001-snapshot-format-v2.md``).
"""

from __future__ import annotations

import io
import json
import struct
import zlib
from dataclasses import asdict
from functools import lru_cache
from itertools import chain
from typing import Any

import numpy as np

from lessmap.core.errors import GraphError
from lessmap.core.paper.covgraph import CovGraphState
from lessmap.core.paper.params import PartitionParams
from lessmap.core.paper.partitioner import FrameRecord, Partitioner, PartitionerState
from lessmap.core.paper.submaps import Submap

SNAPSHOT_VERSION = 2
_MAGIC = b"LMSNAP2\n"
_CRC = struct.Struct("<I")
_LENGTH = struct.Struct("<I")
_DTYPES = {"<i8": np.int64}  # every array of a snapshot is int64
_ARRAYS = (
    "history_seqs",
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


def _ragged(rows: list[np.ndarray] | list[tuple[int, ...]]) -> tuple[np.ndarray, np.ndarray]:
    """Pack rows of ints (arrays, or tuples of Python ints) as (offsets, values)."""
    offsets = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum(np.fromiter(map(len, rows), dtype=np.int64, count=len(rows)), out=offsets[1:])
    if rows and isinstance(rows[0], np.ndarray):
        values = np.concatenate(rows).astype(np.int64, copy=False)
    else:  # tuples: one pass over the ints, no array per row
        values = np.fromiter(chain.from_iterable(rows), dtype=np.int64, count=int(offsets[-1]))
    return offsets, values


def _unragged(offsets: np.ndarray, values: np.ndarray) -> list[np.ndarray]:
    return [values[offsets[i] : offsets[i + 1]] for i in range(offsets.size - 1)]


@lru_cache(maxsize=64)
def _params_meta(params: PartitionParams) -> dict[str, Any]:
    """The parameters as ``meta`` holds them, made once per parameter set (never mutate it)."""
    return {k: str(v) if k == "seed_mode" else v for k, v in asdict(params).items()}


def to_bytes(partitioner: Partitioner) -> bytes:
    """Serialize a partitioner's whole state (format: module docstring)."""
    state = partitioner.state()
    history_offsets, history_values = _ragged([r.features for r in state.history])
    closed_offsets, closed_values = _ragged([s.features for s in state.closed_submaps])
    meta: dict[str, Any] = {
        "version": SNAPSHOT_VERSION,
        "params": _params_meta(state.params),
        "closed": [[s.id, s.first_seq, s.last_seq, s.frame_count] for s in state.closed_submaps],
        "submap_id": state.submap_id,
        "submap_first_seq": state.submap_first_seq,
        "submap_frame_count": state.submap_frame_count,
        "last_seq": state.last_seq,
        "last_stamp_s": state.last_stamp_s.hex(),  # hex keeps the float exact
        "last_features": list(state.last_features),
        "pending_frames": state.pending_frames,
        "pending_nonempty": state.pending_nonempty,
        "frames_since_transition": state.frames_since_transition,
        "frames_applied": state.frames_applied,
        "transitions": state.transitions,
    }
    graph = state.graph
    arrays = {
        "history_seqs": np.fromiter(
            (r.seq for r in state.history), dtype=np.int64, count=len(state.history)
        ),
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
    blobs: list[bytes] = []
    table: list[list[Any]] = []
    offset = 0
    for name, array in arrays.items():
        kind = "<i8"
        blob = np.ascontiguousarray(array, dtype=kind).tobytes()
        table.append([name, kind, list(array.shape), offset, len(blob)])
        blobs.append(blob)
        offset += len(blob)
    header = json.dumps({"meta": meta, "arrays": table}, separators=(",", ":")).encode()
    rest = b"".join([_LENGTH.pack(len(header)), header, *blobs])
    return _MAGIC + _CRC.pack(zlib.crc32(rest)) + rest


def _array(name: str, entry: Any, data: memoryview) -> np.ndarray:
    """One array of the header's table, checked against its declared dtype and shape."""
    if not (isinstance(entry, list) and len(entry) == 5):
        msg = f"array {name!r}: malformed entry"
        raise GraphError(msg)
    _name, kind, shape, offset, size = entry
    dtype = _DTYPES.get(kind)
    if (
        dtype is None
        or not isinstance(shape, list)
        or not all(type(n) is int and n >= 0 for n in shape)
        or type(offset) is not int
        or type(size) is not int
        or not 0 <= offset <= offset + size <= len(data)
    ):
        msg = f"array {name!r}: unsupported entry {entry!r:.80}"
        raise GraphError(msg)
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if count * 8 != size:
        msg = f"array {name!r}: {size} bytes for shape {shape}"
        raise GraphError(msg)
    return np.frombuffer(data[offset : offset + size], dtype=dtype).reshape(shape).copy()


def _read_v2(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    start = len(_MAGIC) + _CRC.size
    if len(data) < start + _LENGTH.size:
        msg = "snapshot truncated"
        raise GraphError(msg)
    (crc,) = _CRC.unpack_from(data, len(_MAGIC))
    rest = memoryview(data)[start:]
    if zlib.crc32(rest) != crc:
        msg = "snapshot damaged: CRC-32 mismatch"
        raise GraphError(msg)
    (length,) = _LENGTH.unpack_from(rest)
    header = json.loads(bytes(rest[_LENGTH.size : _LENGTH.size + length]).decode())
    if not isinstance(header, dict):
        msg = "snapshot header is not a JSON object"
        raise GraphError(msg)
    meta, table = header.get("meta"), header.get("arrays")
    if not isinstance(meta, dict) or not isinstance(table, list):
        msg = "snapshot header has no meta object and arrays list"
        raise GraphError(msg)
    entries = {entry[0]: entry for entry in table if isinstance(entry, list) and entry}
    blobs = rest[_LENGTH.size + length :]
    arrays = {name: _array(name, entries.get(name), blobs) for name in _ARRAYS}
    meta["history_seqs"] = arrays.pop("history_seqs").tolist()
    return meta, arrays


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
            last_stamp_s=float.fromhex(meta["last_stamp_s"]),
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
        # numpy, zipfile or json report it, is one error type for the caller.
        msg = f"not a partitioner snapshot: {type(exc).__name__}: {exc}"
        raise GraphError(msg) from exc

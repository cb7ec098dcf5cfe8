"""A partitioner's whole state as bytes and back, bit-exact.

Format (version 2): a ``lessmap.core.paper.framing`` record with the magic ``LMSNAP2`` + newline,
``meta`` the scalars, every array int64. The CRC catches a damaged record, as the zip
archive's did; the standard library only (the core imports no codec). Version 1, an
uncompressed NumPy ``.npz`` archive with a JSON ``meta`` entry, is still read (records
stored before an upgrade), never written (why: ``docs/decisions/0001-snapshot-format-v2.md``).
"""

from __future__ import annotations

from dataclasses import asdict
from functools import lru_cache
from itertools import chain
from typing import Any

import numpy as np

from lessmap.core.errors import GraphError
from lessmap.core.paper.covgraph import CovGraphState
from lessmap.core.paper.framing import frame, read_npz, unframe
from lessmap.core.paper.params import PartitionParams
from lessmap.core.paper.partitioner import FrameRecord, Partitioner, PartitionerState
from lessmap.core.paper.submaps import Submap

SNAPSHOT_VERSION = 2
_MAGIC = b"LMSNAP2\n"
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
    return frame(_MAGIC, meta, {name: np.asarray(a, dtype=np.int64) for name, a in arrays.items()})


def _read_v2(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    meta, arrays = unframe(data, _MAGIC, dict.fromkeys(_ARRAYS, "<i8"))
    meta["history_seqs"] = arrays.pop("history_seqs").tolist()
    return meta, arrays


def _read_v1(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """A version-1 snapshot (npz, JSON meta; the stamp as a float hex string)."""
    meta, arrays = read_npz(data)
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

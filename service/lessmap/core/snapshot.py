"""A partitioner's whole state as bytes and back, bit-exact.

Format: an uncompressed NumPy ``.npz`` archive (no pickled objects, ``allow_pickle=False``)
holding the arrays plus one ``meta`` entry, a UTF-8 JSON document of the scalars. Chosen
because it stores int64 and float64 arrays exactly and is readable from any language with an
npz reader; the version number changes whenever the layout does.
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict
from typing import Any

import numpy as np

from lessmap.core.covgraph import CovGraphState
from lessmap.core.errors import GraphError
from lessmap.core.params import PartitionParams
from lessmap.core.partitioner import FrameRecord, Partitioner, PartitionerState
from lessmap.core.submaps import Submap

SNAPSHOT_VERSION = 1


def _ragged(rows: list[list[int]] | list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Pack a list of int lists as (offsets, values)."""
    lengths = np.array([len(r) for r in rows], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    values = (
        np.concatenate([np.asarray(r, dtype=np.int64) for r in rows])
        if rows
        else np.zeros(0, dtype=np.int64)
    )
    return offsets, values.astype(np.int64)


def _unragged(offsets: np.ndarray, values: np.ndarray) -> list[np.ndarray]:
    return [values[offsets[i] : offsets[i + 1]] for i in range(offsets.size - 1)]


def to_bytes(partitioner: Partitioner) -> bytes:
    """Serialize a partitioner's whole state."""
    state = partitioner.state()
    history_offsets, history_values = _ragged([r.features for r in state.history])
    closed_offsets, closed_values = _ragged([list(s.features) for s in state.closed_submaps])
    meta: dict[str, Any] = {
        "version": SNAPSHOT_VERSION,
        "params": {k: str(v) if k == "seed_mode" else v for k, v in asdict(state.params).items()},
        "history_seqs": [r.seq for r in state.history],
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
    arrays = {
        "meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
        "feature_ids": state.graph.feature_ids,
        "counts": state.graph.counts,
        "first_seen": state.graph.first_seen,
        "edge_indptr": state.graph.edge_indptr,
        "edge_indices": state.graph.edge_indices,
        "edge_counts": state.graph.edge_counts,
        "history_offsets": history_offsets,
        "history_values": history_values,
        "closed_offsets": closed_offsets,
        "closed_values": closed_values,
    }
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def from_bytes(data: bytes) -> Partitioner:
    """Rebuild a partitioner from ``to_bytes`` output.

    Raises:
        GraphError: the bytes are not a snapshot of a supported version.
    """
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
        meta = json.loads(arrays["meta"].tobytes().decode())
        if meta.get("version") != SNAPSHOT_VERSION:
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

"""A ``RoomTracker``'s whole state as bytes and back, bit-exact.

Format (version 2): a ``lessmap.core.paper.framing`` record with the magic ``LMROOM1`` +
newline, as the other methods' snapshots: ``meta`` is the JSON document of the parameters
and scalars (floats as hex strings, which keep them exact), int64 arrays hold the window's
frames, the kept seqs, the cuts and the segment's and areas' counts in their dicts' order,
and float64 arrays the window's similarities and lag profile. Version 1 was an ``.npz``
archive with ``meta`` as an array: still read, never written.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import numpy as np

from lessmap.core.areas.snapshot import _pack, _unpack
from lessmap.core.errors import GraphError
from lessmap.core.paper.framing import frame, unframe_or_npz
from lessmap.core.rooms.params import RoomParams
from lessmap.core.rooms.tracker import RoomTracker
from lessmap.core.rooms.window import Cut

ROOMS_SNAPSHOT_VERSION = 2
_READABLE_VERSIONS = (1, ROOMS_SNAPSHOT_VERSION)
_MAGIC = b"LMROOM1\n"
_ARRAYS = {
    **dict.fromkeys(
        (
            "frame_seqs",
            "frame_offsets",
            "frame_values",
            "lag_seen",
            "cuts",
            "seqs",
            "segment_features",
            "segment_counts",
            "area_offsets",
            "area_features",
            "area_counts",
        ),
        "<i8",
    ),
    "rows": "<f8",
    "lag_mean": "<f8",
}
_INT_FIELDS = (
    "segment_id",
    "segment_first_seq",
    "segment_frame_count",
    "segment_nonempty",
    "current",
    "last_boundary",
    "last_seq",
    "frames_applied",
    "transitions",
)


def _hex(params: RoomParams) -> dict[str, Any]:
    return {k: v.hex() if isinstance(v, float) else v for k, v in asdict(params).items()}


def _params(d: dict[str, Any]) -> RoomParams:
    defaults = asdict(RoomParams())
    floats = {k for k, v in defaults.items() if isinstance(v, float)}
    flags = {k for k, v in defaults.items() if isinstance(v, bool)}
    values: dict[str, Any] = {
        k: float.fromhex(v) if k in floats else bool(v) if k in flags else int(v)
        for k, v in d.items()
    }
    # Snapshots from before the sure-cut rule and the relative window keep deciding as they did.
    values.setdefault("sure_cut", float("inf"))
    values.setdefault("sure_features", 1)
    values.setdefault("window_relative", False)
    return RoomParams(**values)


def to_bytes(tracker: RoomTracker) -> bytes:
    """Serialize a room tracker's whole state."""
    window = tracker.window
    meta: dict[str, Any] = {
        "version": ROOMS_SNAPSHOT_VERSION,
        "params": _hex(tracker.params),
        "last_stamp_s": tracker.last_stamp_s.hex(),
        "area_frames": list(tracker.area_frames),
        "cut_scores": [cut.score.hex() for cut in tracker.cuts],
        **{name: getattr(tracker, name) for name in _INT_FIELDS},
    }
    frame_offsets, frame_values = _pack([sorted(f) for _, f in window.frames])
    area_offsets, area_features = _pack([list(counts) for counts in tracker.areas])
    _, area_counts = _pack([list(counts.values()) for counts in tracker.areas])
    span = (window.frames.maxlen or 1) - 1
    rows = np.stack(list(window.rows)) if window.rows else np.zeros((0, span))
    arrays = {
        "frame_seqs": np.asarray([seq for seq, _ in window.frames], dtype=np.int64),
        "frame_offsets": frame_offsets,
        "frame_values": frame_values,
        "rows": rows.astype(np.float64),
        "lag_mean": window.lag_mean,
        "lag_seen": window.lag_seen,
        "cuts": np.asarray(
            [[c.boundary_seq, c.width, c.ahead] for c in tracker.cuts], dtype=np.int64
        ).reshape(-1, 3),
        "seqs": np.asarray(list(tracker.seqs), dtype=np.int64),
        "segment_features": np.asarray(list(tracker.segment_counts), dtype=np.int64),
        "segment_counts": np.asarray(list(tracker.segment_counts.values()), dtype=np.int64),
        "area_offsets": area_offsets,
        "area_features": area_features,
        "area_counts": area_counts,
    }
    return frame(_MAGIC, meta, arrays)


def from_bytes(data: bytes) -> RoomTracker:
    """Rebuild a room tracker from ``to_bytes`` output.

    Raises:
        GraphError: the bytes are not a room snapshot of a supported version.
    """
    try:
        meta, arrays = unframe_or_npz(data, _MAGIC, _ARRAYS, "room snapshot")
        if meta.get("version") not in _READABLE_VERSIONS:
            msg = f"room snapshot version {meta.get('version')!r}, expected "
            msg += " or ".join(map(str, _READABLE_VERSIONS))
            raise GraphError(msg)
        tracker = RoomTracker(_params(meta["params"]))
        window = tracker.window
        frames = _unpack(arrays["frame_offsets"], arrays["frame_values"])
        for seq, features in zip(arrays["frame_seqs"].tolist(), frames, strict=True):
            window.frames.append((int(seq), frozenset(features)))
        window.rows.extend(np.array(row, dtype=np.float64) for row in arrays["rows"])
        window.lag_mean = np.array(arrays["lag_mean"], dtype=np.float64)
        window.lag_seen = np.array(arrays["lag_seen"], dtype=np.int64)
        scores = [float.fromhex(v) for v in meta["cut_scores"]]
        for (boundary, width, ahead), score in zip(arrays["cuts"].tolist(), scores, strict=True):
            tracker.cuts.append(Cut(boundary_seq=boundary, score=score, width=width, ahead=ahead))
        tracker.seqs.extend(int(s) for s in arrays["seqs"].tolist())
        tracker.segment_counts = dict(
            zip(
                arrays["segment_features"].tolist(),
                arrays["segment_counts"].tolist(),
                strict=True,
            )
        )
        tracker.areas = [
            dict(zip(features, counts, strict=True))
            for features, counts in zip(
                _unpack(arrays["area_offsets"], arrays["area_features"]),
                _unpack(arrays["area_offsets"], arrays["area_counts"]),
                strict=True,
            )
        ]
        tracker.area_frames = [int(n) for n in meta["area_frames"]]
        tracker.last_stamp_s = float.fromhex(meta["last_stamp_s"])
        for name in _INT_FIELDS:
            value = meta[name]
            setattr(tracker, name, None if value is None else int(value))
    except GraphError:
        raise
    except Exception as exc:  # damaged bytes of any kind: one error type
        msg = f"not a room snapshot: {type(exc).__name__}: {exc}"
        raise GraphError(msg) from exc
    return tracker

"""An ``AreaTracker``'s whole state as bytes and back, bit-exact.

Format: a ``lessmap.core.paper.framing`` record with the magic ``LMAREA1`` + newline, like the
paper partitioner's (``lessmap.core.paper.snapshot``): ``proposer`` (uint8) holds that
snapshot's bytes, ragged int64 arrays hold the areas' counts (in their dicts' order, which
the likelihoods of rule 5 are summed in) and the kept frames, and ``meta`` is the JSON
document of the scalars, the areas' frame counts and the merged areas. Versions 7-9 were
NumPy ``.npz`` archives with ``meta`` as an array; they are still read, never written.
The version number changes whenever the layout does (2: frame counts per area and merges,
for recognition and merging; 3: the parameter ``familiar_relative``; 4: ``weak_ncut`` and
``weak_frames``; 5: ``blind_span`` and ``blind_margin``; 6: ``seam_frames``; 7:
``period_steps``, the last stamp steps and the kept frames that follow a stamp gap; 8:
``max_area_sightings``; 9: ``max_features_kept`` and the sampler's threshold; 10: the
framing instead of ``.npz``; 11: ``spans_in_views`` and its lag profile).
"""

from __future__ import annotations

from dataclasses import asdict
from functools import lru_cache
from itertools import chain
from operator import itemgetter
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.core.areas.sampling import KEEP_ALL, FeatureSampler
from lessmap.core.areas.tracker import AreaParams, AreaTracker, Candidate
from lessmap.core.errors import GraphError
from lessmap.core.paper import snapshot
from lessmap.core.paper.framing import frame, unframe_or_npz
from lessmap.core.paper.submaps import Reason

if TYPE_CHECKING:
    from collections.abc import Collection, Sequence

AREAS_SNAPSHOT_VERSION = 11
_MAGIC = b"LMAREA1\n"
#: Version 7 is version 8 without ``max_area_sightings`` (it reads as the default): sessions
#: checkpointed before the bound resume under it. Versions 7 and 8 have no sampling: their
#: sessions resume keeping every feature (``max_features_kept`` 0), as they did.
READABLE_VERSIONS = (7, 8, 9, 10, AREAS_SNAPSHOT_VERSION)
_ARRAYS = {
    "proposer": "|u1",
    **dict.fromkeys(
        (
            "frame_offsets",
            "frame_values",
            "area_offsets",
            "area_features",
            "area_counts",
            "segment_features",
            "segment_counts",
        ),
        "<i8",
    ),
}

_POOL_FIELDS = {"pool_first_seq": "first_seq", "pool_frames": "frames", "pool_index": "index"}
_INT_FIELDS = (
    "segment_id",
    "segment_first_seq",
    "segment_frame_count",
    "current",
    "last_seq",
    "frames_applied",
    "transitions",
)


def _pack(rows: Sequence[Collection[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Pack rows of ints as (offsets, values), in one pass over the ints (no list per row)."""
    lengths = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    values = np.fromiter(chain.from_iterable(rows), dtype=np.int64, count=int(offsets[-1]))
    return offsets, values


def _unpack(offsets: np.ndarray, values: np.ndarray) -> list[list[int]]:
    return [values[offsets[i] : offsets[i + 1]].tolist() for i in range(offsets.size - 1)]


@lru_cache(maxsize=64)
def _params_meta(params: AreaParams) -> dict[str, Any]:
    """The parameters as ``meta`` holds them, made once per parameter set (never mutate it).

    Every checkpoint of every session writes them; ``asdict`` copies them field by field.
    """
    found = asdict(params)
    found["proposal"] = {k: str(v) if k == "seed_mode" else v for k, v in found["proposal"].items()}
    return found


def to_bytes(tracker: AreaTracker) -> bytes:
    """Serialize an area tracker's whole state."""
    params = _params_meta(tracker.params)
    candidate = tracker.candidate
    meta: dict[str, Any] = {
        "version": AREAS_SNAPSHOT_VERSION,
        "params": params,
        "pool": sorted(tracker.pool.features),
        "pool_starts": [list(pair) for pair in tracker.pool.starts],
        "frame_seqs": list(map(itemgetter(0), tracker.frames)),
        "steps": [step.hex() for step in tracker.steps],
        "gaps": [list(gap) for gap in tracker.gaps],
        "area_frames": list(tracker.area_frames),
        "merged": [[gone, into] for gone, into in tracker.merged.items()],
        "last_stamp_s": tracker.last_stamp_s.hex(),  # hex keeps the float exact
        "sample_threshold": tracker.sampler.threshold,
        # the lag profile (rules 3a, 3c): learnt only with spans_in_views, so kept only then
        "view_lag_mean": [x.hex() for x in tracker.lag_mean.tolist()]
        if tracker.params.spans_in_views
        else [],
        "view_lag_seen": tracker.lag_seen.tolist() if tracker.params.spans_in_views else [],
        "candidate": None
        if candidate is None
        else {
            "boundary_seq": candidate.boundary_seq,
            "seq": candidate.seq,
            "reason": str(candidate.reason),
            "ncut": None if candidate.ncut is None else candidate.ncut.hex(),
            "lambda2": None if candidate.lambda2 is None else candidate.lambda2.hex(),
            "boundary_features": list(candidate.boundary_features),
        },
        **{name: getattr(tracker.pool, field) for name, field in _POOL_FIELDS.items()},
        **{name: getattr(tracker, name) for name in _INT_FIELDS},
    }
    frame_offsets, frame_values = _pack(list(map(itemgetter(1), tracker.frames)))
    area_offsets, area_features = _pack(tracker.areas)  # a dict's keys, in its order
    _, area_counts = _pack([counts.values() for counts in tracker.areas])
    arrays = {
        "proposer": np.frombuffer(snapshot.to_bytes(tracker.proposer), dtype=np.uint8),
        "frame_offsets": frame_offsets,
        "frame_values": frame_values,
        "area_offsets": area_offsets,
        "area_features": area_features,
        "area_counts": area_counts,
        "segment_features": np.asarray(list(tracker.segment_counts), dtype=np.int64),
        "segment_counts": np.asarray(list(tracker.segment_counts.values()), dtype=np.int64),
    }
    return frame(_MAGIC, meta, arrays)


def from_bytes(data: bytes) -> AreaTracker:
    """Rebuild an area tracker from ``to_bytes`` output.

    Raises:
        GraphError: the bytes are not an area snapshot of a supported version.
    """
    try:
        meta, arrays = unframe_or_npz(data, _MAGIC, _ARRAYS, "area snapshot")
        if meta.get("version") not in READABLE_VERSIONS:
            msg = f"area snapshot version {meta.get('version')!r}, expected one of "
            msg += ", ".join(map(str, READABLE_VERSIONS))
            raise GraphError(msg)
        proposer = snapshot.from_bytes(arrays["proposer"].tobytes())
        fields = dict(meta["params"])
        fields["proposal"] = proposer.params
        fields.setdefault("max_features_kept", 0)  # versions 7, 8: every feature kept
        fields.setdefault("spans_in_views", False)  # versions 7-10: spans in frames
        tracker = AreaTracker(AreaParams(**fields))
        tracker.sampler = FeatureSampler(
            tracker.params.max_features_kept, meta.get("sample_threshold", KEEP_ALL)
        )
        tracker.proposer = proposer
        tracker.pool.features = set(meta["pool"])
        tracker.pool.starts.extend((int(i), int(s)) for i, s in meta["pool_starts"])
        frames = _unpack(arrays["frame_offsets"], arrays["frame_values"])
        tracker.frames.extend(
            (int(seq), tuple(features))
            for seq, features in zip(meta["frame_seqs"], frames, strict=True)
        )
        tracker.areas = [
            dict(zip(features, counts, strict=True))
            for features, counts in zip(
                _unpack(arrays["area_offsets"], arrays["area_features"]),
                _unpack(arrays["area_offsets"], arrays["area_counts"]),
                strict=True,
            )
        ]
        tracker.segment_counts = dict(
            zip(
                arrays["segment_features"].tolist(),
                arrays["segment_counts"].tolist(),
                strict=True,
            )
        )
        tracker.steps.extend(float.fromhex(step) for step in meta["steps"])
        tracker.gaps.extend((int(seq), int(missing)) for seq, missing in meta["gaps"])
        tracker.sightings = sum(map(len, tracker.areas))
        tracker.area_frames = [int(n) for n in meta["area_frames"]]
        tracker.merged = {int(gone): int(into) for gone, into in meta["merged"]}
        for name, field in _POOL_FIELDS.items():
            setattr(tracker.pool, field, meta[name])
        for name in _INT_FIELDS:
            setattr(tracker, name, meta[name])
        tracker.last_stamp_s = float.fromhex(meta["last_stamp_s"])
        lag_mean, lag_seen = meta.get("view_lag_mean", []), meta.get("view_lag_seen", [])
        tracker.lag_mean[: len(lag_mean)] = [float.fromhex(x) for x in lag_mean]
        tracker.lag_seen[: len(lag_seen)] = lag_seen
        found = meta["candidate"]
        if found is not None:
            tracker.candidate = Candidate(
                boundary_seq=found["boundary_seq"],
                seq=found["seq"],
                reason=Reason(found["reason"]),
                ncut=None if found["ncut"] is None else float.fromhex(found["ncut"]),
                lambda2=None if found["lambda2"] is None else float.fromhex(found["lambda2"]),
                boundary_features=tuple(found["boundary_features"]),
            )
    except GraphError:
        raise
    except Exception as exc:
        # Snapshot bytes come from storage or another instance: anything malformed, however
        # numpy, zipfile or json report it, is one error type for the caller.
        msg = f"not an area snapshot: {type(exc).__name__}: {exc}"
        raise GraphError(msg) from exc
    return tracker

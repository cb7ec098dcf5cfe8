"""The record of a segmenter's whole state (``lessmap.core.segmenter``), bit-exact.

Format (version 1): magic ``LMSEGM1``, CRC-32, a JSON header, then the sections: ``inner``,
the wrapped method's own snapshot, then int64 arrays (in full: ``docs/design/segmenter.md``).

Rules of this file:

1. The method's snapshot is kept whole: this record only adds what a segmenter keeps beside it.
2. The partitioner snapshot's framing, standard library and numpy only; floats as hex
   strings, which keep them exact; segment features as int64 arrays, not JSON ints.
3. Whatever is malformed is one ``GraphError`` with one line saying what.
4. A bare partitioner snapshot (older checkpoints) is not a record (``is_record``) and reads
   as a paper segmenter.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.core.areas.graph import AreaGraphBuilder, _Stats
from lessmap.core.errors import GraphError
from lessmap.core.paper.submaps import Reason, Submap, Transition

if TYPE_CHECKING:
    from collections.abc import Mapping

    from numpy.typing import NDArray

SEGMENTER_SNAPSHOT_VERSION = 1
MAGIC = b"LMSEGM1\n"
_CRC = struct.Struct("<I")
_LENGTH = struct.Struct("<I")
_INNER = "inner"


@dataclass(frozen=True, slots=True)
class Record:
    """A record's parts: which method, its JSON meta, its method's snapshot, its arrays."""

    method: str
    meta: dict[str, Any]
    inner: bytes
    arrays: dict[str, NDArray[np.int64]]


def is_record(data: bytes) -> bool:
    """Whether ``data`` claims to be a segmenter record (rather than an older snapshot)."""
    return data.startswith(MAGIC)


def pack(
    method: str, meta: Mapping[str, Any], inner: bytes, arrays: Mapping[str, NDArray[np.int64]]
) -> bytes:
    """Frame a record (format: module docstring)."""
    blobs = [inner, *(np.ascontiguousarray(a, dtype="<i8").tobytes() for a in arrays.values())]
    names = [_INNER, *arrays]
    header = {
        "version": SEGMENTER_SNAPSHOT_VERSION,
        "method": method,
        "meta": meta,
        "sections": [[name, len(blob)] for name, blob in zip(names, blobs, strict=True)],
    }
    encoded = json.dumps(header, separators=(",", ":")).encode()
    rest = b"".join([_LENGTH.pack(len(encoded)), encoded, *blobs])
    return MAGIC + _CRC.pack(zlib.crc32(rest)) + rest


def unpack(data: bytes) -> Record:
    """Check a record's framing and return its parts.

    Raises:
        GraphError: the bytes are not a whole, undamaged record of a supported version.
    """
    try:
        return _unpack(data)
    except GraphError:
        raise
    except Exception as exc:  # json, UTF-8 or struct: one error type for the caller (rule 3)
        msg = f"not a segmenter snapshot: {type(exc).__name__}: {exc}"
        raise GraphError(msg) from exc


def _unpack(data: bytes) -> Record:
    start = len(MAGIC) + _CRC.size
    if not is_record(data):
        msg = "not a segmenter snapshot: wrong magic"
        raise GraphError(msg)
    if len(data) < start + _LENGTH.size:
        msg = "segmenter snapshot truncated"
        raise GraphError(msg)
    (crc,) = _CRC.unpack_from(data, len(MAGIC))
    rest = memoryview(data)[start:]
    if zlib.crc32(rest) != crc:
        msg = "segmenter snapshot damaged: CRC-32 mismatch"
        raise GraphError(msg)
    (length,) = _LENGTH.unpack_from(rest)
    if _LENGTH.size + length > len(rest):
        msg = f"segmenter snapshot header of {length} bytes overruns the record"
        raise GraphError(msg)
    header = json.loads(bytes(rest[_LENGTH.size : _LENGTH.size + length]).decode())
    if not isinstance(header, dict):
        msg = "segmenter snapshot header is not a JSON object"
        raise GraphError(msg)
    if header.get("version") != SEGMENTER_SNAPSHOT_VERSION:
        found = header.get("version")
        msg = f"segmenter snapshot version {found!r}, expected {SEGMENTER_SNAPSHOT_VERSION}"
        raise GraphError(msg)
    method, meta, sections = header.get("method"), header.get("meta"), header.get("sections")
    if not (isinstance(method, str) and isinstance(meta, dict) and isinstance(sections, list)):
        msg = "segmenter snapshot header has no method, meta and sections"
        raise GraphError(msg)
    body = rest[_LENGTH.size + length :]
    parts: dict[str, bytes] = {}
    offset = 0
    for entry in sections:
        name, size = entry
        if not (isinstance(name, str) and type(size) is int and size >= 0):
            msg = f"segmenter snapshot section {entry!r:.60} is malformed"
            raise GraphError(msg)
        parts[name] = bytes(body[offset : offset + size])
        offset += size
    if offset != len(body) or _INNER not in parts:
        msg = f"segmenter snapshot sections hold {offset} bytes of {len(body)}, or no inner"
        raise GraphError(msg)
    inner = parts.pop(_INNER)
    arrays = {
        name: np.frombuffer(blob, dtype="<i8").astype(np.int64) for name, blob in parts.items()
    }
    return Record(method=method, meta=meta, inner=inner, arrays=arrays)


# -- the parts: segments, transitions, the area graph's sums ----------------------------------


def hex_or_none(value: float | None) -> str | None:
    """A float as its exact hex string (None stays None)."""
    return None if value is None else value.hex()


def float_or_none(value: str | None) -> float | None:
    """The float of ``hex_or_none``."""
    return None if value is None else float.fromhex(value)


def submap_json(submap: Submap) -> list[Any]:
    """A segment as a JSON list, features included (for the few of a pending change)."""
    s = submap
    return [s.id, s.first_seq, s.last_seq, s.frame_count, list(s.features)]


def submap_of(row: list[Any]) -> Submap:
    """The segment of ``submap_json``."""
    segment_id, first, last, frames, features = row
    return Submap(
        id=segment_id, first_seq=first, last_seq=last, frame_count=frames, features=tuple(features)
    )


def submaps_unpack(rows: list[list[int]], arrays: Mapping[str, NDArray[np.int64]]) -> list[Submap]:
    """The segments of ``ClosedSegments.pack``."""
    offsets, values = arrays["submap_offsets"], arrays["submap_values"]
    if offsets.size != len(rows) + 1 or (offsets.size and offsets[-1] != values.size):
        msg = f"segmenter snapshot: {len(rows)} segments, {offsets.size} feature offsets"
        raise GraphError(msg)
    return [
        Submap(
            id=segment_id,
            first_seq=first,
            last_seq=last,
            frame_count=frames,
            features=tuple(values[offsets[i] : offsets[i + 1]].tolist()),
        )
        for i, (segment_id, first, last, frames) in enumerate(rows)
    ]


def transition_json(t: Transition) -> dict[str, Any]:
    """A transition as a JSON object, floats exact."""
    return {
        "seq": t.seq,
        "boundary_seq": t.boundary_seq,
        "stamp_s": t.stamp_s.hex(),
        "reason": str(t.reason),
        "ncut": hex_or_none(t.ncut),
        "lambda2": hex_or_none(t.lambda2),
        "closed": submap_json(t.closed),
        "opened": submap_json(t.opened),
        "boundary_features": list(t.boundary_features),
        "batch_frames": t.batch_frames,
    }


def transition_of(d: Mapping[str, Any]) -> Transition:
    """The transition of ``transition_json``."""
    return Transition(
        seq=d["seq"],
        boundary_seq=d["boundary_seq"],
        stamp_s=float.fromhex(d["stamp_s"]),
        reason=Reason(d["reason"]),
        ncut=float_or_none(d["ncut"]),
        lambda2=float_or_none(d["lambda2"]),
        closed=submap_of(d["closed"]),
        opened=submap_of(d["opened"]),
        boundary_features=tuple(d["boundary_features"]),
        batch_frames=d["batch_frames"],
    )


# ``AreaGraphBuilder`` keeps its sums private, for its own rules; saving and loading them is
# the one use outside ``area_graph``, kept here so that a change there shows up in one place.


def builder_json(builder: AreaGraphBuilder) -> dict[str, Any]:
    """An area graph builder's sums as a JSON object, in their dicts' order."""
    return {
        "max_boundary_features": builder.max_boundary_features,
        "areas": [
            [area, s.frames, s.visits, s.first_seq, s.last_seq]
            for area, s in builder._areas.items()
        ],
        "passages": [[left, entered, n] for (left, entered), n in builder._passages.items()],
        "boundary": [
            [low, high, [[f, n] for f, n in seen.items()]]
            for (low, high), seen in builder._boundary.items()
        ],
    }


def builder_of(d: Mapping[str, Any]) -> AreaGraphBuilder:
    """The builder of ``builder_json``."""
    builder = AreaGraphBuilder(d["max_boundary_features"])
    builder._areas = {
        area: _Stats(frames, visits, first, last)
        for area, frames, visits, first, last in d["areas"]
    }
    builder._passages = {(left, entered): n for left, entered, n in d["passages"]}
    builder._boundary = {
        (low, high): Counter({f: n for f, n in seen}) for low, high, seen in d["boundary"]
    }
    return builder

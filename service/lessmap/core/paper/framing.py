"""Named arrays beside a JSON document in one checked record: the snapshots' framing.

Format: a magic of the caller's, the CRC-32 of the rest (4 bytes, little-endian), the length
of the header (4 bytes, little-endian), the header (UTF-8 JSON: ``meta``, the caller's
document, and ``arrays``, a list of [name, dtype, shape, offset, bytes]), then the arrays'
raw little-endian bytes back to back. Readable from any language with JSON and a CRC, built
with the standard library and numpy only; it replaced NumPy's ``.npz`` archive, whose zip
members cost more than the state they held (``docs/decisions/0001-snapshot-format-v2.md``).
"""

from __future__ import annotations

import io
import json
import struct
import zlib
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.core.errors import GraphError

if TYPE_CHECKING:
    from collections.abc import Mapping

    from numpy.typing import NDArray

_CRC = struct.Struct("<I")
_LENGTH = struct.Struct("<I")
#: The element types a record may hold, by their NumPy names (little-endian).
DTYPES: dict[str, type[np.generic]] = {"<i8": np.int64, "<f8": np.float64, "|u1": np.uint8}


def frame(magic: bytes, meta: Mapping[str, Any], arrays: Mapping[str, NDArray[Any]]) -> bytes:
    """One record of ``meta`` and ``arrays`` (each int64, float64 or uint8)."""
    blobs: list[bytes] = []
    table: list[list[Any]] = []
    offset = 0
    for name, array in arrays.items():
        kind = array.dtype.newbyteorder("<").str
        if kind not in DTYPES:
            msg = f"array {name!r}: dtype {array.dtype} cannot be framed"
            raise TypeError(msg)
        blob = np.ascontiguousarray(array, dtype=kind).tobytes()
        table.append([name, kind, list(array.shape), offset, len(blob)])
        blobs.append(blob)
        offset += len(blob)
    header = json.dumps({"meta": meta, "arrays": table}, separators=(",", ":")).encode()
    rest = b"".join([_LENGTH.pack(len(header)), header, *blobs])
    return magic + _CRC.pack(zlib.crc32(rest)) + rest


def unframe(
    data: bytes, magic: bytes, kinds: Mapping[str, str], what: str = "snapshot"
) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """The ``meta`` and the arrays of a ``frame`` record (writable copies).

    ``kinds`` names the arrays wanted and the dtype each must have (a ``DTYPES`` key).

    Raises:
        GraphError: not a whole, undamaged record with those arrays (``what`` names it).
    """
    start = len(magic) + _CRC.size
    if not data.startswith(magic):
        msg = f"{what}: wrong magic"
        raise GraphError(msg)
    if len(data) < start + _LENGTH.size:
        msg = f"{what} truncated"
        raise GraphError(msg)
    (crc,) = _CRC.unpack_from(data, len(magic))
    rest = memoryview(data)[start:]
    if zlib.crc32(rest) != crc:
        msg = f"{what} damaged: CRC-32 mismatch"
        raise GraphError(msg)
    (length,) = _LENGTH.unpack_from(rest)
    header = json.loads(bytes(rest[_LENGTH.size : _LENGTH.size + length]).decode())
    if not isinstance(header, dict):
        msg = f"{what} header is not a JSON object"
        raise GraphError(msg)
    meta, table = header.get("meta"), header.get("arrays")
    if not isinstance(meta, dict) or not isinstance(table, list):
        msg = f"{what} header has no meta object and arrays list"
        raise GraphError(msg)
    entries = {entry[0]: entry for entry in table if isinstance(entry, list) and entry}
    blobs = rest[_LENGTH.size + length :]
    return meta, {
        name: _array(name, kind, entries.get(name), blobs) for name, kind in kinds.items()
    }


def unframe_or_npz(
    data: bytes, magic: bytes, kinds: Mapping[str, str], what: str = "snapshot"
) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """``unframe``, or ``read_npz`` for records written before the framing."""
    if data.startswith(magic):
        return unframe(data, magic, kinds, what)
    return read_npz(data, what)


def read_npz(data: bytes, what: str = "snapshot") -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """The meta and arrays of an ``.npz`` archive with a JSON ``meta`` array (older records).

    Raises:
        GraphError: the meta is not a JSON object (numpy and json raise their own errors).
    """
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        arrays = {name: archive[name] for name in archive.files}
    meta = json.loads(arrays.pop("meta").tobytes().decode())
    if not isinstance(meta, dict):
        msg = f"{what} meta is not a JSON object"
        raise GraphError(msg)
    return meta, arrays


def _array(name: str, wanted: str, entry: Any, data: memoryview) -> NDArray[Any]:
    """One array of the header's table, checked against its declared dtype and shape."""
    if not (isinstance(entry, list) and len(entry) == 5):
        msg = f"array {name!r}: malformed entry"
        raise GraphError(msg)
    _name, kind, shape, offset, size = entry
    dtype = DTYPES.get(kind) if kind == wanted else None
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
    if count * np.dtype(dtype).itemsize != size:
        msg = f"array {name!r}: {size} bytes for shape {shape}"
        raise GraphError(msg)
    return np.frombuffer(data[offset : offset + size], dtype=kind).reshape(shape).copy()

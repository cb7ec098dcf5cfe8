"""What the store keeps of one robot's session, and its bytes between instances.

A record is the checkpoint of a robot's current session (``open``), of one evicted while
idle (``evicted``), or the final record of a closed one (``closed``, no segmenter bytes).
Instances ship records to each other (``to_bytes``); the newer one wins (``newer_than``).
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass
from typing import Any

import msgpack

RobotKey = tuple[str, str]  # (fleet, robot)

_WIRE_VERSION = 2  # of a record shipped between instances (SessionRecord.to_bytes); 2: zlib


@dataclass(frozen=True, slots=True, kw_only=True)
class SessionRecord:
    """What the store keeps of one robot's session."""

    fleet: str
    robot: str
    session: str
    status: str  # "open" | "evicted" | "closed"
    last_seq: int | None  # highest seq received when the record was taken
    meta: dict[str, Any]  # counters, gap ranges, closed session ids, final state (JSON)
    snapshot: bytes | None  # lessmap.core.paper.snapshot bytes; None once closed
    updated_s: float  # wall clock (time.time) of the record

    @property
    def key(self) -> RobotKey:
        """(fleet, robot)."""
        return (self.fleet, self.robot)

    @property
    def epoch(self) -> int:
        """Partition epoch of the instance that wrote the record (1 if it had none)."""
        return int(self.meta.get("epoch", 1))

    def newer_than(self, other: SessionRecord | None) -> bool:
        """True when this record supersedes ``other`` (a higher epoch, then a higher seq)."""
        if other is None:
            return True
        mine = (self.epoch, -1 if self.last_seq is None else self.last_seq)
        theirs = (other.epoch, -1 if other.last_seq is None else other.last_seq)
        return mine > theirs

    def to_bytes(self) -> bytes:
        """Serialize for shipping to another instance (service-internal, msgpack)."""
        return bytes(
            msgpack.packb(
                {
                    "ckpt": _WIRE_VERSION,
                    "fleet": self.fleet,
                    "robot": self.robot,
                    "session": self.session,
                    "status": self.status,
                    "last_seq": self.last_seq,
                    "meta": json.dumps(self.meta),
                    # zlib level 1: most bytes gone for little CPU (docs/tuning/checkpoints.md).
                    "snapshot": None if self.snapshot is None else zlib.compress(self.snapshot, 1),
                    "updated_s": self.updated_s,
                },
                use_bin_type=True,
            )
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> SessionRecord:
        """Read a shipped record; ValueError when it is not one."""
        try:
            obj = msgpack.unpackb(data, raw=False, strict_map_key=True)
            if not isinstance(obj, dict) or obj.get("ckpt") != _WIRE_VERSION:
                msg = f"not a version-{_WIRE_VERSION} checkpoint record"
                raise ValueError(msg)
            record = cls(
                fleet=str(obj["fleet"]),
                robot=str(obj["robot"]),
                session=str(obj["session"]),
                status=str(obj["status"]),
                last_seq=None if obj["last_seq"] is None else int(obj["last_seq"]),
                meta=json.loads(obj["meta"]),
                snapshot=None
                if obj["snapshot"] is None
                else zlib.decompress(bytes(obj["snapshot"])),
                updated_s=float(obj["updated_s"]),
            )
        except (KeyError, TypeError, ValueError, msgpack.UnpackException, zlib.error) as exc:
            msg = f"unreadable checkpoint record: {exc}"
            raise ValueError(msg) from exc
        if record.status not in ("open", "evicted", "closed") or not isinstance(record.meta, dict):
            msg = f"unreadable checkpoint record: status {record.status!r}"
            raise ValueError(msg)
        return record

"""A fleet walking through rooms with poses, and the lessmap view/record processes."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
from typing import TYPE_CHECKING, Any

import pytest

pytest.importorskip("foxglove", reason="the [viz] extra is not installed")

if TYPE_CHECKING:
    from pathlib import Path

    from lessmap_client.connection import Connection

FRAMES_PER_ROOM = 15
ROOMS = 2


def walk(room_offset: float = 0.0) -> list[tuple[list[int], tuple[float, float, float]]]:
    """Frames of a robot crossing ``ROOMS`` rooms of 8 features each, with poses along x."""
    frames = []
    for room in range(ROOMS):
        tags = [100 * room + i for i in range(1, 9)]
        for k in range(FRAMES_PER_ROOM):
            seen = [tags[(k + j) % 8] for j in range(5)]
            x = 10.0 * room + 0.5 * k
            frames.append((seen, (x, room_offset, 0.0)))
    return frames


def publish_walks(conn: Connection, fleet: str, robots: list[str]) -> None:
    """Publish every robot's walk (robots interleaved) and end their sessions."""
    publishers = [conn.robot(fleet, robot) for robot in robots]
    for publisher in publishers:
        assert publisher.wait_for_service(20)
    walks = [walk(2.0 * i) for i in range(len(robots))]
    for step in range(len(walks[0])):
        for publisher, frames in zip(publishers, walks, strict=True):
            features, pose = frames[step]
            publisher.publish(features, stamp_s=100.0 + step, pose=pose)
    # Sessions stay open: the viewer's state table shows them as they are.


def start_command(tmp_path: Path, name: str, *argv: str) -> subprocess.Popen[str]:
    with (tmp_path / f"{name}.log").open("w") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "lessmap", "-v", *argv],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
            env=dict(os.environ),
        )


def stop_command(process: subprocess.Popen[str]) -> dict[str, Any]:
    process.send_signal(signal.SIGTERM)
    try:
        out, _ = process.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(5)
        raise
    assert process.returncode == 0
    summary: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return summary


# -- Foxglove messages back to dicts ----------------------------------------------------------
# foxglove-sdk's message classes only encode, and no protobuf library is a test dependency:
# this reads the protobuf wire format with the field names of the schema each message class
# carries (a FileDescriptorSet), enough for the scene's messages.


def _varint(data: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, at


def _fields(data: bytes) -> list[tuple[int, int | bytes]]:
    """Return (field number, raw value) pairs: an int (varint, fixed) or bytes."""
    out: list[tuple[int, int | bytes]] = []
    at = 0
    while at < len(data):
        key, at = _varint(data, at)
        number, kind = key >> 3, key & 7
        if kind == 0:
            value, at = _varint(data, at)
            out.append((number, value))
        elif kind == 1:
            out.append((number, int.from_bytes(data[at : at + 8], "little")))
            at += 8
        elif kind == 2:
            size, at = _varint(data, at)
            out.append((number, data[at : at + size]))
            at += size
        elif kind == 5:
            out.append((number, int.from_bytes(data[at : at + 4], "little")))
            at += 4
        else:
            msg = f"wire type {kind}"
            raise ValueError(msg)
    return out


def _descriptors(schema: bytes) -> dict[str, dict[int, tuple[str, int, str, bool]]]:
    """Return per message type (".pkg.Name"): number -> (name, type, type name, repeated)."""
    types: dict[str, dict[int, tuple[str, int, str, bool]]] = {}

    def message(data: bytes, scope: str) -> None:
        name = next(v for n, v in _fields(data) if n == 1)
        assert isinstance(name, bytes)
        full = f"{scope}.{name.decode()}"
        fields = types.setdefault(full, {})
        for n, v in _fields(data):
            if n == 2 and isinstance(v, bytes):  # FieldDescriptorProto
                f = dict(_fields(v))
                type_name = f.get(6, b"")
                assert isinstance(type_name, bytes)
                fields[int(f[3])] = (
                    bytes(f[1]).decode() if isinstance(f[1], bytes) else "",
                    int(f[5]),
                    type_name.decode(),
                    f.get(4) == 3,
                )
            elif n == 3 and isinstance(v, bytes):  # nested DescriptorProto
                message(v, full)

    for n, file in _fields(schema):
        if n == 1 and isinstance(file, bytes):
            parts = dict(_fields(file))
            package = parts.get(2, b"")
            assert isinstance(package, bytes)
            for m, v in _fields(file):
                if m == 4 and isinstance(v, bytes):
                    message(v, f".{package.decode()}" if package else "")
    return types


#: proto3 defaults by field type: double, float, string, message (any other: 0).
_DEFAULTS: dict[int, Any] = {1: 0.0, 2: 0.0, 9: "", 11: None}


def decode(message: Any) -> dict[str, Any]:
    """Return a foxglove-sdk message (e.g. ``foxglove.messages.SceneEntity``) as a dict.

    Every field of the schema is present: repeated ones as lists, unset ones as their
    proto3 default (None for a message).
    """
    schema = message.get_schema()
    types = _descriptors(schema.data)

    def read(data: bytes, type_name: str) -> dict[str, Any]:
        spec = types[type_name]
        value: dict[str, Any] = {
            name: [] if repeated else _DEFAULTS.get(kind, 0)
            for name, kind, _, repeated in spec.values()
        }
        for number, raw in _fields(data):
            if number not in spec:
                continue
            name, kind, sub, repeated = spec[number]
            items: list[Any]
            if kind == 11:
                assert isinstance(raw, bytes)
                items = [read(raw, sub)]
            elif kind == 9:
                assert isinstance(raw, bytes)
                items = [raw.decode()]
            elif kind == 1 and isinstance(raw, bytes):  # packed doubles
                items = list(struct.unpack(f"<{len(raw) // 8}d", raw))
            elif kind == 1:
                assert isinstance(raw, int)
                items = [struct.unpack("<d", raw.to_bytes(8, "little"))[0]]
            elif isinstance(raw, int):
                items = [raw]
            else:
                pos, items = 0, []
                while pos < len(raw):  # packed varints
                    item, pos = _varint(raw, pos)
                    items.append(item)
            if repeated:
                value[name] += items
            else:
                value[name] = items[-1]
        return value

    return read(message.encode(), f".{schema.name}")

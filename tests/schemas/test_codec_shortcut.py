"""decode_inbound's shortcut for plain frames decides exactly as the full decode path."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgpack
import pytest
from hypothesis import given, settings, strategies as st

from lessmap_schemas import (
    DEFAULT_LIMITS,
    MESSAGE_TYPES,
    ErrorCode,
    Frame,
    Message,
    SessionEnd,
    WireError,
    WireLimits,
    decode,
    decode_inbound,
    encode,
)
from lessmap_schemas.codec import _plain_frame
from tests.schemas.samples import FRAME, samples
from tests.schemas.test_fuzz import FUZZ, SMALL, frames, keys, leaves

VECTORS = Path(__file__).resolve().parents[2] / "schemas" / "vectors"
LIMITS = [DEFAULT_LIMITS, SMALL, WireLimits(max_features_per_frame=2)]


def full(data: bytes, limits: WireLimits) -> Message | tuple[ErrorCode, str | None, str]:
    try:
        return decode(data, (Frame, SessionEnd), limits)
    except WireError as exc:
        return (exc.code, exc.limit, str(exc))


def assert_same(data: bytes, limits: WireLimits = DEFAULT_LIMITS) -> Message | None:
    """decode_inbound (shortcut first) and decode (full path) agree on everything."""
    expected = full(data, limits)
    try:
        got: Message | tuple[ErrorCode, str | None, str] = decode_inbound(data, limits)
    except WireError as exc:
        got = (exc.code, exc.limit, str(exc))
    assert type(got) is type(expected)
    assert got == expected
    if isinstance(got, Message) and isinstance(expected, Message):
        assert got.model_fields_set == expected.model_fields_set
        assert list(got.__dict__) == list(expected.__dict__)
        assert encode(got) == encode(expected)
        return got
    return None


def vector_payloads() -> list[Any]:
    out = []
    for kind in MESSAGE_TYPES:
        data = json.loads((VECTORS / f"{kind}.json").read_text(encoding="utf-8"))
        for group in ("valid", "invalid"):
            for case in data[group]:
                out.append(pytest.param(bytes.fromhex(case["hex"]), id=f"{kind}-{case['name']}"))
    return out


@pytest.mark.parametrize("limits", LIMITS, ids=["default", "small", "two-features"])
@pytest.mark.parametrize("data", vector_payloads())
def test_every_golden_vector_decides_the_same(data: bytes, limits: WireLimits) -> None:
    assert_same(data, limits)


def test_plain_frames_take_the_shortcut() -> None:
    for message in samples():
        if isinstance(message, Frame):
            frame = _plain_frame(encode(message), DEFAULT_LIMITS)
            assert frame == message
    without_pose = msgpack.packb({k: v for k, v in FRAME.model_dump().items() if k != "pose"})
    assert _plain_frame(without_pose, DEFAULT_LIMITS) is not None
    assert assert_same(without_pose) is not None


def test_tightened_limits_leave_the_shortcut() -> None:
    tight = WireLimits(max_name_len=8)
    assert _plain_frame(encode(FRAME), tight) is None
    assert_same(encode(FRAME), tight)


def repeated(field: str) -> bytes:
    """A Frame without pose, ``field`` twice: 7 pairs, the header of a Frame with a pose."""
    fields = {k: v for k, v in FRAME.model_dump().items() if k != "pose"}
    pairs = [*fields.items(), (field, fields[field])]
    payload = bytearray(msgpack.Packer().pack_map_header(len(pairs)))
    for name, item in pairs:
        payload += msgpack.packb(name) + msgpack.packb(item, use_bin_type=True)
    return bytes(payload)


@pytest.mark.parametrize("field", ["type", "v", "session", "seq", "stamp_s", "features"])
def test_a_repeated_key_is_invalid_on_both_paths(field: str) -> None:
    data = repeated(field)
    assert data[0] == 0x87
    # Without the duplicates, what is left is a valid Frame: only the header tells.
    assert decode(msgpack.packb(msgpack.unpackb(data)), Frame) is not None
    assert _plain_frame(data, DEFAULT_LIMITS) is None
    with pytest.raises(WireError) as info:
        decode_inbound(data)
    assert info.value.code is ErrorCode.INVALID
    assert "twice" in str(info.value)


def test_a_repeated_key_inside_a_value_is_decided_by_the_full_path() -> None:
    # A map where a number is expected: the validator refuses it, the full path names it.
    nested = bytearray(b"\x87")
    for name, value in FRAME.model_dump().items():
        nested += msgpack.packb(name)
        if name == "pose":
            nested += b"\x82" + msgpack.packb("a") + b"\x01" + msgpack.packb("a") + b"\x02"
        else:
            nested += msgpack.packb(value, use_bin_type=True)
    assert _plain_frame(bytes(nested), DEFAULT_LIMITS) is None
    assert_same(bytes(nested))


@FUZZ
@given(frames, st.sampled_from(LIMITS))
def test_random_frames(frame: Frame, limits: WireLimits) -> None:
    assert_same(encode(frame), limits)


@FUZZ
@given(
    st.dictionaries(keys, leaves | st.lists(leaves, max_size=4), max_size=3),
    st.lists(keys, max_size=2),
    st.sampled_from(LIMITS),
)
def test_mutated_frame_fields(changes: dict[str, Any], drop: list[str], limits: WireLimits) -> None:
    fields = {**FRAME.model_dump(), **changes}
    for name in drop:
        fields.pop(name, None)
    assert_same(msgpack.packb(fields, use_bin_type=True), limits)


@settings(FUZZ)
@given(st.data(), st.sampled_from(LIMITS))
def test_mutated_frame_bytes(data: st.DataObject, limits: WireLimits) -> None:
    payload = bytearray(encode(FRAME))
    for _ in range(data.draw(st.integers(1, 3))):
        at = data.draw(st.integers(0, len(payload) - 1)) if payload else 0
        if payload and data.draw(st.booleans()):
            payload[at] ^= data.draw(st.integers(1, 255))
        else:
            payload[at:at] = data.draw(st.binary(min_size=1, max_size=4))
    assert_same(bytes(payload), limits)

"""Garbage in, WireError out: every payload decodes to a message or raises WireError."""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

import msgpack
from hypothesis import HealthCheck, given, settings, strategies as st

from lessmap_schemas import (
    DEFAULT_LIMITS,
    MESSAGE_TYPES,
    Error,
    ErrorCode,
    Frame,
    InvalidNameError,
    Message,
    SessionEnd,
    WireError,
    WireLimits,
    decode,
    decode_inbound,
    encode,
    keys as lessmap_keys,
)
from lessmap_schemas.partition import PARTITIONS, partition_of
from tests.schemas.samples import samples

# Random cases per property in the default run; a long fuzz run is one variable away
# (LESSMAP_FUZZ_EXAMPLES=20000 python -m pytest tests/schemas/test_fuzz.py).
EXAMPLES = int(os.environ.get("LESSMAP_FUZZ_EXAMPLES", "600"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,  # never write .hypothesis/ into the checkout
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
LIMIT_NAMES = {field.name for field in dataclasses.fields(WireLimits)}
EXPECTED: list[Any] = [Frame, SessionEnd, (Frame, SessionEnd), *MESSAGE_TYPES.values()]
GOOD = [encode(message) for message in samples()]
SMALL = WireLimits(
    max_payload_bytes=600,
    max_features_per_frame=5,
    max_name_len=6,
    max_seq=1000,
    max_feature_id=1000,
    max_detail_len=40,
    max_list_len=4,
)


def outcome(data: bytes, expected: Any, limits: WireLimits = DEFAULT_LIMITS) -> Message | WireError:
    """Decode and check the one promise: a message of an expected type, or a WireError."""
    result: Message | WireError
    try:
        result = decode(data, expected, limits)
    except WireError as exc:
        result = exc
    if isinstance(result, WireError):
        assert isinstance(result.code, ErrorCode)
        assert result.limit is None or result.limit in LIMIT_NAMES
        assert (result.code is ErrorCode.LIMIT_EXCEEDED) <= (result.limit is not None)
        assert 0 < len(str(result)) <= 1024  # fits Error.detail as it is
        return result
    types: tuple[type[Message], ...] = expected if isinstance(expected, tuple) else (expected,)
    assert isinstance(result, types)
    assert decode(encode(result), type(result), limits) == result
    return result


readers = st.tuples(st.sampled_from(EXPECTED), st.sampled_from([DEFAULT_LIMITS, SMALL]))


def everywhere(data: bytes) -> None:
    """Decode as the service does, and as every client reader would."""
    for expected in EXPECTED:
        outcome(data, expected)
    outcome(data, (Frame, SessionEnd), SMALL)


@FUZZ
@given(st.binary(max_size=600))
def test_random_bytes(data: bytes) -> None:
    everywhere(data)


keys = st.sampled_from(sorted({f for model in MESSAGE_TYPES.values() for f in model.model_fields}))
leaves = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=16)
    | st.binary(max_size=8)
    | st.sampled_from([*MESSAGE_TYPES, "SubmapSummary", "SPECTRAL", "SEQ_GAP", 1, 2**53, 2**63])
)
values = st.recursive(
    leaves,
    lambda children: (
        st.lists(children, max_size=6)
        | st.dictionaries(keys | st.text(max_size=8), children, max_size=6)
    ),
    max_leaves=10,
)


@settings(FUZZ, max_examples=max(1, EXAMPLES // 2))  # nested values cost ~3 ms each to generate
@given(values, readers)
def test_random_msgpack_values(value: object, reader: tuple[Any, WireLimits]) -> None:
    outcome(msgpack.packb(value, use_bin_type=True), *reader)


@FUZZ
@given(
    st.sampled_from(samples()),
    st.dictionaries(keys, leaves | st.lists(leaves, max_size=4), max_size=3),
    st.lists(keys, max_size=3),
    st.sampled_from([DEFAULT_LIMITS, SMALL]),
)
def test_mutated_fields(
    message: Message, changes: dict[str, Any], drop: list[str], limits: WireLimits
) -> None:
    fields = {**message.model_dump(), **changes}
    for name in drop:
        fields.pop(name, None)
    outcome(msgpack.packb(fields, use_bin_type=True), type(message), limits)


@FUZZ
@given(st.sampled_from(GOOD), st.data(), readers)
def test_mutated_bytes(good: bytes, data: st.DataObject, reader: tuple[Any, WireLimits]) -> None:
    payload = bytearray(good)
    for _ in range(data.draw(st.integers(1, 4))):
        action = data.draw(st.sampled_from(["flip", "truncate", "insert", "delete"]))
        at = data.draw(st.integers(0, max(len(payload) - 1, 0)))
        if action == "flip" and payload:
            payload[at] ^= data.draw(st.integers(1, 255))
        elif action == "truncate":
            del payload[at:]
        elif action == "insert":
            payload[at:at] = data.draw(st.binary(min_size=1, max_size=9))
        elif payload:
            del payload[at : at + data.draw(st.integers(1, 9))]
    outcome(bytes(payload), *reader)


@FUZZ
@given(st.integers(1, 64), st.binary(min_size=1, max_size=200))
def test_oversized_payloads_are_refused_unread(limit: int, data: bytes) -> None:
    limits = WireLimits(max_payload_bytes=limit)
    result = outcome(data, Frame, limits)
    if len(data) > limit:
        assert isinstance(result, WireError)
        assert (result.code, result.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_payload_bytes")


names = st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}", fullmatch=True)
frames = st.builds(
    Frame,
    session=names,
    seq=st.integers(0, 2**53 - 1),
    stamp_s=st.floats(allow_nan=False, allow_infinity=False),
    features=st.lists(st.integers(0, 2**63 - 1), max_size=20),
    pose=st.none() | st.tuples(*[st.floats(allow_nan=False, allow_infinity=False)] * 3),
)


@settings(FUZZ, max_examples=max(1, EXAMPLES // 2))
@given(frames)
def test_valid_frames_round_trip(frame: Frame) -> None:
    data = encode(frame)
    assert decode_inbound(data) == frame
    assert encode(decode(data, Frame)) == data
    assert all(math.isfinite(x) for x in frame.pose or ())


@settings(FUZZ, max_examples=max(1, EXAMPLES // 2))
@given(st.sampled_from(samples()), keys, st.integers(0, 1100), leaves)
def test_deeply_nested_values(message: Message, field: str, depth: int, leaf: object) -> None:
    # msgpack-python cannot pack past 511 levels, so the map is assembled by hand.
    fields: dict[str, Any] = message.model_dump()
    fields.setdefault(field, None)
    payload = bytearray(msgpack.Packer().pack_map_header(len(fields)))
    for name, value in fields.items():
        payload += msgpack.packb(name)
        if name == field:
            payload += b"\x91" * depth + msgpack.packb(leaf, use_bin_type=True)
        else:
            payload += msgpack.packb(value, use_bin_type=True)
    outcome(bytes(payload), type(message))
    outcome(bytes(payload), (Frame, SessionEnd), SMALL)


@FUZZ
@given(st.sampled_from(samples()), st.integers(-(2**63), 2**64 - 1) | st.floats() | st.none())
def test_any_version_but_4_is_refused(message: Message, version: object) -> None:
    fields = {**message.model_dump(), "v": version}
    result = outcome(msgpack.packb(fields, use_bin_type=True), type(message))
    if version == 4 and type(version) is int:
        assert not isinstance(result, WireError)
    else:
        assert isinstance(result, WireError)
        assert result.code is ErrorCode.UNSUPPORTED_VERSION


V2_FIELDS = [
    (model, name)
    for model in MESSAGE_TYPES.values()
    for name in ("partition", "epoch", "partitions", "standby", "queue_depth", "lag_s")
    if name in model.model_fields
]


@FUZZ
@given(st.sampled_from(V2_FIELDS), st.data())
def test_v2_fields_take_only_their_range(field: tuple[type[Message], str], data: Any) -> None:
    model, name = field
    message = next(m for m in samples() if type(m) is model)
    value = data.draw(leaves | st.lists(leaves, max_size=4) | st.integers(-5, 70))
    result = outcome(raw_with(message, name, value), model)
    if isinstance(result, WireError):
        return
    accepted = getattr(result, name)
    if name == "epoch" and value is None:
        assert model is Error  # only an Error may name no epoch
    elif name in ("partition", "epoch", "queue_depth"):
        assert type(value) is int
        bounds = {"partition": (0, PARTITIONS - 1), "epoch": (1, 2**53 - 1)}
        low, high = bounds.get(name, (0, 2**53 - 1))
        assert low <= value <= high
    elif name in ("partitions", "standby"):
        assert all(type(p) is int for p in accepted)
        assert all(0 <= p < PARTITIONS for p in accepted)
    else:
        assert math.isfinite(accepted)
        assert accepted >= 0


def raw_with(message: Message, name: str, value: object) -> bytes:
    data: bytes = msgpack.packb({**message.model_dump(), name: value}, use_bin_type=True)
    return data


def parsed(parse: Any, key: str) -> Any:
    """Return what a key parser returns, or the InvalidNameError it raises (nothing else)."""
    try:
        return parse(key)
    except InvalidNameError as exc:
        return exc


def refused(result: object) -> bool:
    """Check that a refusal is a one-line-sized BAD_NAME; tell whether it was one."""
    if not isinstance(result, InvalidNameError):
        return False
    assert result.code is ErrorCode.BAD_NAME
    assert 0 < len(str(result)) <= 1024
    return True


chunks = st.text(max_size=8) | st.integers(-100, 200).map(str) | st.sampled_from(["", "*", "**"])


@FUZZ
@given(names, names, chunks)
def test_frames_keys_need_the_robots_own_partition(fleet: str, robot: str, chunk: str) -> None:
    key = f"lessmap/v4/{fleet}/{robot}/frames/{chunk}"
    result = parsed(lessmap_keys.parse_robot_key, key)
    if refused(result):
        assert chunk != str(partition_of(fleet, robot))
    else:
        assert result == (fleet, robot, "frames")
        assert lessmap_keys.frames(fleet, robot) == key
    # Without its partition chunk a frames key names no robot's frames.
    assert refused(parsed(lessmap_keys.parse_robot_key, f"lessmap/v4/{fleet}/{robot}/frames"))


@FUZZ
@given(
    st.lists(
        st.text(max_size=12)
        | st.sampled_from(["lessmap", "v4", "v3", "v2", "v1", "frames", "@", "0", "63"]),
        max_size=8,
    )
)
def test_hostile_keys_parse_or_raise_bad_name(parts: list[str]) -> None:
    key = "/".join(parts)
    for parse in (
        lessmap_keys.parse_robot_key,
        lessmap_keys.parse_submap_key,
        lessmap_keys.parse_checkpoint_key,
    ):
        refused(parsed(parse, key))

from __future__ import annotations

import dataclasses
import math
import pickle
import tracemalloc
from typing import Any

import msgpack
import pytest
from pydantic import ValidationError

from lessmap_schemas import (
    DEFAULT_LIMITS,
    MESSAGE_TYPES,
    Error,
    ErrorCode,
    Frame,
    InvalidNameError,
    Message,
    SessionEnd,
    SessionState,
    SubmapSummary,
    Transition,
    WireError,
    WireLimits,
    decode,
    decode_inbound,
    encode,
    encoding,
)
from tests.schemas.samples import CLOSED, FRAME, samples


def pack(value: object) -> bytes:
    data: bytes = msgpack.packb(value, use_bin_type=True)
    return data


def raw(message: Message, **changes: object) -> bytes:
    """Encode a message with some fields replaced, bypassing validation."""
    fields: dict[str, Any] = message.model_dump()
    fields.update(changes)
    return pack(fields)


def rejects(data: bytes, expected: Any, limits: WireLimits = DEFAULT_LIMITS) -> WireError:
    with pytest.raises(WireError) as info:
        decode(data, expected, limits)
    return info.value


@pytest.mark.parametrize("message", samples(), ids=lambda m: type(m).__name__)
def test_round_trip(message: Message) -> None:
    data = encode(message)
    back = decode(data, type(message))
    assert back == message
    assert type(back) is type(message)
    assert encode(back) == data


@pytest.mark.parametrize("message", samples(), ids=lambda m: type(m).__name__)
def test_encoding_is_a_map_in_field_order(message: Message) -> None:
    fields = msgpack.unpackb(encode(message))
    assert list(fields) == list(type(message).model_fields)
    assert list(fields)[:2] == ["type", "v"]
    assert fields["type"] == type(message).__name__
    assert fields["v"] == 4


def test_floats_are_float64_and_ints_are_minimal() -> None:
    data = encode(Frame(session="s", seq=1, stamp_s=2.0, features=[3]))
    assert b"\xa7stamp_s\xcb" in data  # float64 even for an integral value
    assert b"\xa3seq\x01" in data  # positive fixint


def test_encoding_names_type_and_version() -> None:
    assert encoding(FRAME) == "application/msgpack;lessmap.Frame/4"
    assert encoding(Transition) == "application/msgpack;lessmap.Transition/4"
    assert {encoding(model) for model in MESSAGE_TYPES.values()} == {
        f"application/msgpack;lessmap.{name}/4" for name in MESSAGE_TYPES
    }


def test_decode_inbound_takes_frames_and_session_ends_only() -> None:
    end = SessionEnd(session="run-1", last_seq=3, stamp_s=1.0)
    assert decode_inbound(encode(FRAME)) == FRAME
    assert decode_inbound(encode(end)) == end
    transition = next(m for m in samples() if isinstance(m, Transition))
    with pytest.raises(WireError) as info:
        decode_inbound(encode(transition))
    assert info.value.code is ErrorCode.UNKNOWN_TYPE
    assert "Frame, SessionEnd" in str(info.value)


def test_decode_checks_the_expected_type() -> None:
    error = rejects(encode(FRAME), SessionEnd)
    assert error.code is ErrorCode.UNKNOWN_TYPE
    assert decode(encode(FRAME), (SessionEnd, Frame)) == FRAME


def test_expected_must_be_a_message_type() -> None:
    # A local bug, not remote input: not a WireError.
    with pytest.raises(TypeError):
        decode(encode(FRAME), SubmapSummary)  # type: ignore[type-var]
    with pytest.raises(TypeError):
        decode(encode(FRAME), ())


@pytest.mark.parametrize(
    ("changes", "code"),
    [
        ({"seq": "5"}, ErrorCode.INVALID),
        ({"seq": True}, ErrorCode.INVALID),
        ({"seq": 5.0}, ErrorCode.INVALID),
        ({"seq": -1}, ErrorCode.INVALID),
        ({"stamp_s": math.nan}, ErrorCode.INVALID),
        ({"stamp_s": -math.inf}, ErrorCode.INVALID),
        ({"stamp_s": True}, ErrorCode.INVALID),
        ({"features": [1, "2"]}, ErrorCode.INVALID),
        ({"features": (1, 2.5)}, ErrorCode.INVALID),
        ({"pose": [1.0, 2.0]}, ErrorCode.INVALID),
        ({"pose": [1.0, 2.0, math.inf]}, ErrorCode.INVALID),
        ({"session": "a b"}, ErrorCode.BAD_NAME),
        ({"session": 7}, ErrorCode.INVALID),
        ({"extra": 1}, ErrorCode.INVALID),
        ({"v": 1}, ErrorCode.UNSUPPORTED_VERSION),
        ({"v": 2}, ErrorCode.UNSUPPORTED_VERSION),
        ({"v": 3}, ErrorCode.UNSUPPORTED_VERSION),
        ({"v": 4.0}, ErrorCode.UNSUPPORTED_VERSION),
        ({"type": "frame"}, ErrorCode.UNKNOWN_TYPE),
        ({"type": None}, ErrorCode.UNKNOWN_TYPE),
    ],
)
def test_frame_field_violations(changes: dict[str, object], code: ErrorCode) -> None:
    error = rejects(raw(FRAME, **changes), Frame)
    assert error.code is code, str(error)


def test_invalid_errors_name_the_field_and_the_input_type() -> None:
    error = rejects(raw(FRAME, seq=True), Frame)
    assert str(error).startswith("Frame.seq: Input should be a valid integer")
    assert "(got bool)" in str(error)
    nested = rejects(
        raw(SessionState.model_validate(samples()[9]), closed_submaps=[{}]), SessionState
    )
    assert "closed_submaps.0" in str(nested)


def test_integers_are_accepted_for_floats() -> None:
    # JavaScript encoders write 5.0 as the integer 5.
    frame = decode(raw(FRAME, stamp_s=5, pose=[1, 2, 3]), Frame)
    assert frame.stamp_s == 5.0
    assert type(frame.stamp_s) is float
    assert frame.pose == (1.0, 2.0, 3.0)


def test_missing_pose_reads_as_null() -> None:
    fields = FRAME.model_dump()
    del fields["pose"]
    assert decode(pack(fields), Frame).pose is None


def test_error_codes_travel_as_strings() -> None:
    error = next(m for m in samples() if isinstance(m, Error))
    assert msgpack.unpackb(encode(error))["code"] == "SEQ_GAP"
    assert decode(encode(error), Error).code is ErrorCode.SEQ_GAP
    assert rejects(raw(error, code="NOPE"), Error).code is ErrorCode.INVALID


def test_models_are_frozen_and_strict() -> None:
    with pytest.raises(ValidationError):
        Frame(session="s", seq="1", stamp_s=0.0, features=[])
    with pytest.raises(ValidationError):
        FRAME.seq = 43
    with pytest.raises(ValidationError):
        Frame(session="s", seq=1, stamp_s=0.0, features=[], colour="red")


@pytest.mark.parametrize(
    "changes",
    [
        {"boundary_seq": 43},
        {"ncut": None},
        {"reason": "DISCONNECTED"},
        {"closed": {**CLOSED.model_dump(), "first_seq": 42}},
        {"batch_frames": 0},
    ],
)
def test_transition_invariants(changes: dict[str, object]) -> None:
    transition = next(m for m in samples() if isinstance(m, Transition))
    assert rejects(raw(transition, **changes), Transition).code is ErrorCode.INVALID


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\xc1",
        b"\x93\x01",
        b"\x80\x00",
        b"\x81\x01\x02",
        b"\xa2\xff\xfe",
        b"\x91" * 5000,
        b"\x07",
    ],
    ids=["empty", "reserved", "truncated", "trailing", "int-key", "utf8", "deep", "not-a-map"],
)
def test_malformed(data: bytes) -> None:
    error = rejects(data, Frame)
    assert error.code is ErrorCode.MALFORMED
    assert error.limit is None


@pytest.mark.parametrize(
    ("data", "code"),
    [
        (b"\x82\xa4type" + b"\x91" * 1000 + b"\xc0\xa1v\x01", ErrorCode.UNKNOWN_TYPE),
        (b"\x82\xa4type\xa5Frame\xa1v" + b"\x91" * 1000 + b"\xc0", ErrorCode.UNSUPPORTED_VERSION),
        (pack({"type": list(range(4000)), "v": 4}), ErrorCode.UNKNOWN_TYPE),
    ],
    ids=["deep-type", "deep-v", "long-type"],
)
def test_hostile_envelope_values_are_not_echoed(data: bytes, code: ErrorCode) -> None:
    error = rejects(data, Frame)
    assert error.code is code
    assert len(str(error)) < 200


# --- every limit -----------------------------------------------------------------------------


def features_frame(count: int, first: int = 0) -> bytes:
    return raw(FRAME, features=list(range(first, first + count)), pose=None)


def test_payload_limit_is_checked_before_unpacking() -> None:
    # 1 MiB + 1 of garbage: a WireError about size, not about msgpack.
    error = rejects(b"\xc1" * (DEFAULT_LIMITS.max_payload_bytes + 1), Frame)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_payload_bytes")
    small = WireLimits(max_payload_bytes=len(encode(FRAME)))
    assert decode(encode(FRAME), Frame, small) == FRAME
    error = rejects(
        encode(FRAME) + b"", Frame, WireLimits(max_payload_bytes=len(encode(FRAME)) - 1)
    )
    assert error.limit == "max_payload_bytes"


@pytest.mark.parametrize("limit", [2, 10, 4096])
def test_features_per_frame(limit: int) -> None:
    limits = WireLimits(max_features_per_frame=limit)
    assert len(decode(features_frame(limit), Frame, limits).features) == limit
    error = rejects(features_frame(limit + 1), Frame, limits)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_features_per_frame")
    # A pose is 3 floats even when the feature limit is lower.
    assert decode(encode(FRAME), Frame, WireLimits(max_features_per_frame=4)).pose is not None


def test_features_limit_applies_inside_msgpack_too() -> None:
    # An array longer than any frame list anywhere in the payload, e.g. an unknown field.
    fields = {**FRAME.model_dump(), "junk": list(range(5000))}
    error = rejects(pack(fields), Frame)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_features_per_frame")


def test_name_len() -> None:
    error = rejects(raw(FRAME, session="s" * 65), Frame)
    assert (error.code, error.limit) == (ErrorCode.BAD_NAME, "max_name_len")
    assert isinstance(error, InvalidNameError)
    limits = WireLimits(max_name_len=8)
    assert decode(raw(FRAME, session="s" * 8), Frame, limits).session == "s" * 8
    error = rejects(raw(FRAME, session="s" * 9), Frame, limits)
    assert (error.code, error.limit) == (ErrorCode.BAD_NAME, "max_name_len")
    state = samples()[9]
    error = rejects(raw(state, instance="i" * 9), SessionState, limits)
    assert (error.code, error.limit) == (ErrorCode.BAD_NAME, "max_name_len")


def test_seq() -> None:
    error = rejects(raw(FRAME, seq=2**53), Frame)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_seq")
    limits = WireLimits(max_seq=100)
    assert decode(raw(FRAME, seq=100), Frame, limits).seq == 100
    error = rejects(raw(FRAME, seq=101), Frame, limits)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_seq")
    end = SessionEnd(session="s", last_seq=None, stamp_s=0.0)
    error = rejects(raw(end, last_seq=101), SessionEnd, limits)
    assert error.limit == "max_seq"
    transition = next(m for m in samples() if isinstance(m, Transition))
    nested = {**transition.opened.model_dump(), "last_seq": 2**53}
    assert rejects(raw(transition, opened=nested), Transition).limit == "max_seq"
    nested = {**transition.closed.model_dump(), "first_seq": 0, "last_seq": 101}
    assert rejects(raw(transition, closed=nested), Transition, limits).limit == "max_seq"


def test_feature_id() -> None:
    error = rejects(raw(FRAME, features=[2**63]), Frame)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_feature_id")
    error = rejects(raw(FRAME, features=[2**64 - 1]), Frame)
    assert error.limit == "max_feature_id"
    limits = WireLimits(max_feature_id=1000)
    assert decode(raw(FRAME, features=[1000]), Frame, limits).features == [1000]
    error = rejects(raw(FRAME, features=[5, 1001]), Frame, limits)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_feature_id")
    transition = next(m for m in samples() if isinstance(m, Transition))
    error = rejects(raw(transition, boundary_features=[2**63]), Transition)
    assert error.limit == "max_feature_id"
    error = rejects(encode(transition), Transition, WireLimits(max_feature_id=2))
    assert error.limit == "max_feature_id"


def test_detail_len() -> None:
    error_message = next(m for m in samples() if isinstance(m, Error))
    error = rejects(raw(error_message, detail="d" * 1025), Error)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_detail_len")
    limits = WireLimits(max_detail_len=10)
    assert decode(raw(error_message, detail="d" * 10), Error, limits).detail == "d" * 10
    error = rejects(raw(error_message, detail="d" * 11), Error, limits)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_detail_len")
    # No string anywhere may be longer than the longest string field.
    error = rejects(raw(FRAME, note="n" * 1025), Frame)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_detail_len")


def test_list_len() -> None:
    transition = next(m for m in samples() if isinstance(m, Transition))
    limits = WireLimits(max_list_len=5)
    assert decode(raw(transition, boundary_features=[1, 2, 3, 4, 5]), Transition, limits)
    error = rejects(raw(transition, boundary_features=[1, 2, 3, 4, 5, 6]), Transition, limits)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_list_len")
    state = samples()[9]
    error = rejects(raw(state, closed_submaps=[CLOSED.model_dump()] * 6), SessionState, limits)
    assert error.limit == "max_list_len"
    big = SubmapSummary(id=0, first_seq=0, last_seq=0, frame_count=1, features=list(range(100_001)))
    error = rejects(raw(state, current_submap=big.model_dump()), SessionState)
    assert (error.code, error.limit) == (ErrorCode.LIMIT_EXCEEDED, "max_list_len")
    # Mixed expectations still bound service lists by max_list_len.
    error = rejects(raw(transition, boundary_features=[1] * 11), (Frame, Transition), limits)
    assert error.limit == "max_list_len"


def test_every_limit_is_covered() -> None:
    covered = {
        "max_payload_bytes",
        "max_features_per_frame",
        "max_name_len",
        "max_seq",
        "max_feature_id",
        "max_detail_len",
        "max_list_len",
    }
    assert {field.name for field in dataclasses.fields(WireLimits)} == covered


@pytest.mark.parametrize(
    "changes",
    [
        {"max_payload_bytes": 0},
        {"max_features_per_frame": -1},
        {"max_list_len": True},
        {"max_seq": 2**53},
        {"max_feature_id": 2**63},
        {"max_name_len": 65},
        {"max_detail_len": 1025},
    ],
)
def test_limits_are_positive_and_never_loosen_the_format(changes: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="WireLimits"):
        WireLimits(**changes)


def test_tightening_is_detected() -> None:
    assert not DEFAULT_LIMITS.tightens_format
    assert not WireLimits(max_payload_bytes=10, max_list_len=2).tightens_format
    assert WireLimits(max_seq=10).tightens_format


def test_nested_array_headers_do_not_blow_up_memory() -> None:
    # Each header claims 4 Gi items; msgpack would reserve the slots before the items arrive.
    bomb = b"\x81\xa1x" + b"\xdd\xff\xff\xff\xff" * 1000
    tracemalloc.start()
    try:
        for expected in (Frame, Transition):
            assert rejects(bomb, expected).code is ErrorCode.LIMIT_EXCEEDED
        claims = (b"\xdd" + (4096).to_bytes(4, "big")) * 1000
        assert rejects(b"\x81\xa1x" + claims, Frame).code is ErrorCode.MALFORMED
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20


def test_wire_errors_pickle_with_code_and_limit() -> None:
    error = WireError("too big", ErrorCode.LIMIT_EXCEEDED, "max_seq")
    back = pickle.loads(pickle.dumps(error))
    assert (type(back), str(back), back.code, back.limit) == (
        WireError,
        "too big",
        ErrorCode.LIMIT_EXCEEDED,
        "max_seq",
    )
    name_error = pickle.loads(pickle.dumps(InvalidNameError("bad", "max_name_len")))
    assert type(name_error) is InvalidNameError
    assert (name_error.code, name_error.limit) == (ErrorCode.BAD_NAME, "max_name_len")

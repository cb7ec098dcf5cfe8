"""Encode messages to msgpack and decode untrusted bytes back into validated messages.

Decoding is the service's hot path and its attack surface, so the order of checks is fixed:

1. payload size, before a single byte is unpacked (`max_payload_bytes`);
2. msgpack, with every length bounded: an unbounded array header would make msgpack allocate
   its slots before the items arrive, turning kilobytes into gigabytes;
3. envelope: a map, a known `type` accepted here, `v == WIRE_VERSION` (4);
4. `Frame.features` length, on the raw list, before pydantic touches it;
5. pydantic, strict;
6. limits tighter than the format bounds, if the caller set any.

Every failure is a `WireError` carrying an `ErrorCode`. `decode_inbound` tries a shortcut for a
plain `Frame` first; what it does not accept goes through `decode`, whose errors are the rule.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar, cast, overload

import msgpack
from pydantic import BaseModel, ValidationError

from lessmap_schemas.errors import ErrorCode, InvalidNameError, WireError
from lessmap_schemas.keys import WIRE_VERSION, validate_name
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits
from lessmap_schemas.messages import MESSAGE_TYPES, Frame, Message, SessionEnd

if TYPE_CHECKING:
    from pydantic_core import ErrorDetails

M = TypeVar("M", bound=Message)

MEDIA_TYPE = "application/msgpack"
"""Zenoh encoding of every lessmap payload; the schema suffix names the message."""

_INBOUND: frozenset[type[Message]] = frozenset({Frame, SessionEnd})
_MAX_MAP_LEN = 32  # no lessmap map has more fields; bounds hash work on hostile maps
_NAME_FIELDS = frozenset({"fleet", "robot", "session", "instance"})
_SEQ_FIELDS = frozenset({"seq", "last_seq", "boundary_seq", "first_seq", "incarnation"})
_FEATURE_FIELDS = frozenset({"features", "boundary_features"})
_NAME_ERRORS = frozenset({"string_pattern_mismatch", "string_too_short", "string_too_long"})
_LENGTH_ERROR = re.compile(r"(\d+) exceeds max_(str|bin|array|map|ext)_len\((\d+)\)")
_UNPACK_ERRORS = (ValueError, TypeError, OverflowError, RecursionError, msgpack.UnpackException)


class _DuplicateKeyError(ValueError):
    """A map names one key twice (section 4, rule 1)."""


def _unique_keys(pairs: list[tuple[str, object]]) -> dict[str, object]:
    # msgpack-python would keep the last of two equal keys, another reader the first: a
    # payload that two conforming readers could read differently is refused by all.
    out = dict(pairs)
    if len(out) == len(pairs):
        return out
    seen: set[str] = set()
    for key, _ in pairs:
        if key in seen:
            msg = f"a map names the key {_short(key)} twice"
            raise _DuplicateKeyError(msg)
        seen.add(key)
    raise AssertionError  # unreachable: fewer keys than pairs means a repeat


def encoding(message: Message | type[Message]) -> str:
    """Return the Zenoh encoding string of a message, e.g. `application/msgpack;lessmap.Frame/1`.

    Pass it to `zenoh.Encoding(...)`; this package never imports zenoh.
    """
    model = message if isinstance(message, type) else type(message)
    return f"{MEDIA_TYPE};lessmap.{model.__name__}/{WIRE_VERSION}"


def encode(message: Message) -> bytes:
    """Encode a message canonically: a msgpack map in field order, floats as float64."""
    # msgpack packs tuples as arrays and StrEnum members as str, so no conversion pass.
    data: bytes = msgpack.packb(message.model_dump(), use_bin_type=True)
    return data


@overload
def decode(data: bytes, expected: type[M], limits: WireLimits = ...) -> M: ...
@overload
def decode(data: bytes, expected: tuple[type[M], ...], limits: WireLimits = ...) -> M: ...
def decode(
    data: bytes,
    expected: type[Message] | tuple[type[Message], ...],
    limits: WireLimits = DEFAULT_LIMITS,
) -> Message:
    """Decode one untrusted payload into a validated message.

    Args:
        data: The payload bytes, e.g. `sample.payload.to_bytes()`.
        expected: The message type, or types, accepted on the key the payload came from.
        limits: Bounds to enforce; a service passes its configured limits.

    Returns:
        The message, an instance of one of `expected`.

    Raises:
        WireError: For any payload that is not a valid message of an expected type; `code`
            says why and `limit` names the limit that was hit, if any.
    """
    plan = _plan(expected if isinstance(expected, tuple) else (expected,), limits)
    if len(data) > limits.max_payload_bytes:
        msg = f"payload of {len(data)} bytes exceeds max_payload_bytes={limits.max_payload_bytes}"
        raise WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_payload_bytes")
    try:
        obj = msgpack.unpackb(data, **plan.unpack)
    except _UNPACK_ERRORS as exc:
        raise _unpack_error(exc, plan) from exc
    if type(obj) is not dict:
        msg = f"top level is a msgpack {type(obj).__name__}, not a map"
        raise WireError(msg, ErrorCode.MALFORMED)
    name = obj.get("type")
    model = plan.models.get(name) if type(name) is str else None
    if model is None:
        msg = f"type {_short(name)} is not one of {', '.join(plan.models)}"
        raise WireError(msg, ErrorCode.UNKNOWN_TYPE)
    version = obj.get("v")
    if type(version) is not int or version != WIRE_VERSION:
        msg = f"{name} has v={_short(version)}; this reader speaks v={WIRE_VERSION}"
        raise WireError(msg, ErrorCode.UNSUPPORTED_VERSION)
    if model is Frame:
        features = obj.get("features")
        if type(features) is list and len(features) > limits.max_features_per_frame:
            msg = (
                f"Frame has {len(features)} features; "
                f"max_features_per_frame={limits.max_features_per_frame}"
            )
            raise WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_features_per_frame")
    try:
        message = model.model_validate(obj)
    except ValidationError as exc:
        raise _invalid(exc, model, limits) from exc
    if plan.walk:
        _check_limits(message, limits, model.__name__)
    return message


def decode_inbound(data: bytes, limits: WireLimits = DEFAULT_LIMITS) -> Frame | SessionEnd:
    """Decode a payload from a robot's `frames` key: a `Frame` or a `SessionEnd`.

    Raises:
        WireError: As `decode`.
    """
    frame = _plain_frame(data, limits)
    if frame is not None:
        return frame
    return cast("Frame | SessionEnd", decode(data, (Frame, SessionEnd), limits))


# The fixmap headers of a Frame's 6 fields (no pose) and 7 fields (pose, possibly nil).
_FRAME_HEADERS = {0x86: 6, 0x87: 7}
_validate_frame = Frame.__pydantic_validator__.validate_python
# [(limits, unpack options)] of the last limits seen, replaced whole (safe across threads): a
# reader keeps one WireLimits, and hashing it for `_plan`'s cache at every frame would cost.
_shortcut: list[tuple[WireLimits | None, dict[str, Any] | None]] = [(None, None)]


def _plain_frame(data: bytes, limits: WireLimits) -> Frame | None:
    """Return the Frame `decode` would return, or None to let `decode` decide.

    It accepts a subset of what `decode` accepts, with the same result: the payload bound
    and the unpack bounds are `decode`'s; a top-level map of n entries that unpacks to n keys
    repeats none, and a payload the Frame validator accepts holds no other map (every field
    is a string, a number or a list of numbers). Limits that tighten the format bounds, and
    everything unusual, go to `decode`.
    """
    entries = _FRAME_HEADERS.get(data[0]) if data else None
    if entries is None or len(data) > limits.max_payload_bytes:
        return None
    cached, unpack = _shortcut[0]
    if cached is not limits:
        unpack = _shortcut_options(limits)
    if unpack is None:
        return None
    try:
        obj = msgpack.unpackb(data, **unpack)
    except _UNPACK_ERRORS:
        return None
    if type(obj) is not dict or len(obj) != entries:
        return None
    version = obj.get("v")
    features = obj.get("features")
    if (
        obj.get("type") != "Frame"
        or type(version) is not int
        or version != WIRE_VERSION
        or (type(features) is list and len(features) > limits.max_features_per_frame)
    ):
        return None
    try:
        frame: Frame = _validate_frame(obj)
    except ValidationError:
        return None
    return frame


def _shortcut_options(limits: WireLimits) -> dict[str, Any] | None:
    unpack: dict[str, Any] | None = None
    if not limits.tightens_format:
        unpack = dict(_plan((Frame, SessionEnd), limits).unpack)
        del unpack["object_pairs_hook"]
    _shortcut[0] = (limits, unpack)
    return unpack


def _short(value: object) -> str:
    # repr() of a hostile container can be huge or nest past the recursion limit.
    if value is not None and type(value) not in (str, int, float, bool):
        return f"a msgpack {type(value).__name__}"
    text = repr(value)
    return text if len(text) <= 80 else f"{text[:77]}..."


@dataclass(frozen=True, slots=True)
class _Plan:
    """What `decode` needs per (expected types, limits), computed once."""

    models: dict[str, type[Message]]
    unpack: dict[str, Any]
    array_limit: str
    walk: bool


@functools.lru_cache(maxsize=128)
def _plan(expected: tuple[type[Message], ...], limits: WireLimits) -> _Plan:
    unknown = [model for model in expected if MESSAGE_TYPES.get(model.__name__) is not model]
    if not expected or unknown:
        msg = f"expected must name lessmap messages, not {unknown or 'nothing'}"
        raise TypeError(msg)
    inbound = all(model in _INBOUND for model in expected)
    # Robots' arrays are bounded by the per-frame limit, the service's by the list limit;
    # a pose needs 3 slots whatever the limits say.
    arrays = [3, limits.max_features_per_frame if inbound else limits.max_list_len]
    if not inbound and any(model in _INBOUND for model in expected):
        arrays.append(limits.max_features_per_frame)
    unpack = {
        "raw": False,
        "strict_map_key": True,
        "object_pairs_hook": _unique_keys,
        "max_str_len": max(limits.max_detail_len, limits.max_name_len, 32),
        "max_bin_len": 0,  # no message has a bytes field
        "max_ext_len": 0,  # nor an extension type
        "max_array_len": max(arrays),
        "max_map_len": _MAX_MAP_LEN,
    }
    return _Plan(
        models={model.__name__: model for model in expected},
        unpack=unpack,
        array_limit="max_features_per_frame" if inbound else "max_list_len",
        walk=limits.tightens_format or not inbound,
    )


def _unpack_error(exc: BaseException, plan: _Plan) -> WireError:
    if type(exc) is _DuplicateKeyError:
        return WireError(str(exc), ErrorCode.INVALID)
    match = _LENGTH_ERROR.fullmatch(str(exc)) if type(exc) is ValueError else None
    if match is None:
        msg = f"not a msgpack value ({type(exc).__name__}: {exc})"[:512]
        return WireError(msg, ErrorCode.MALFORMED)
    size, kind, bound = match.groups()
    if kind == "array":
        msg = f"an array of {size} items exceeds {plan.array_limit}={bound}"
        return WireError(msg, ErrorCode.LIMIT_EXCEEDED, plan.array_limit)
    if kind == "str":
        msg = f"a string of {size} bytes exceeds max_detail_len={bound}, the longest string field"
        return WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_detail_len")
    if kind == "map":
        msg = f"a map of {size} entries: no lessmap map has more than {bound} fields"
        return WireError(msg, ErrorCode.INVALID)
    msg = f"a msgpack {kind} value: lessmap messages use no binary or extension types"
    return WireError(msg, ErrorCode.INVALID)


def _invalid(exc: ValidationError, model: type[Message], limits: WireLimits) -> WireError:
    error: ErrorDetails = exc.errors(include_url=False)[0]
    loc = error["loc"]
    field = next((part for part in reversed(loc) if isinstance(part, str)), None)
    kind = error["type"]
    where = ".".join(str(part) for part in (model.__name__, *loc))
    value = error["input"]
    if field in _NAME_FIELDS and kind in _NAME_ERRORS and isinstance(value, str):
        try:
            validate_name(value, field, limits)
        except InvalidNameError as bad:
            return bad
    msg = f"{where}: {error['msg']}"
    if kind.endswith("_type"):
        msg += f" (got {type(value).__name__})"
    if kind == "less_than_equal" and field in _SEQ_FIELDS:
        return WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_seq")
    # In a passage's (feature ID, count) pair, index 1 is a count: INVALID like any count.
    pair_count = len(loc) >= 2 and isinstance(loc[-2], int) and loc[-1] == 1
    if kind == "less_than_equal" and field in _FEATURE_FIELDS and not pair_count:
        return WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_feature_id")
    if kind == "string_too_long" and field == "detail":
        return WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_detail_len")
    return WireError(msg[:1024], ErrorCode.INVALID)


def _check_limits(model: BaseModel, limits: WireLimits, where: str) -> None:
    """Enforce list lengths and any format bound the caller tightened, after validation."""
    for field, value in model:
        path = f"{where}.{field}"
        if isinstance(value, BaseModel):
            _check_limits(value, limits, path)
        elif type(value) is list:
            # Frame.features was bounded by max_features_per_frame before validation.
            if len(value) > limits.max_list_len and not isinstance(model, Frame):
                msg = f"{path} has {len(value)} items; max_list_len={limits.max_list_len}"
                raise WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_list_len")
            for index, item in enumerate(value):
                if isinstance(item, BaseModel):
                    _check_limits(item, limits, f"{path}.{index}")
            if field in _FEATURE_FIELDS and value:
                # A passage's boundary features are (feature ID, count) pairs.
                top = max(item[0] for item in value) if type(value[0]) is tuple else max(value)
                if top > limits.max_feature_id:
                    msg = f"{path} holds {top}; max_feature_id={limits.max_feature_id}"
                    raise WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_feature_id")
        elif field in _SEQ_FIELDS and type(value) is int and value > limits.max_seq:
            msg = f"{path}={value} exceeds max_seq={limits.max_seq}"
            raise WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_seq")
        elif field in _NAME_FIELDS and type(value) is str:
            validate_name(value, field, limits)
        elif field == "detail" and type(value) is str and len(value) > limits.max_detail_len:
            msg = f"{path} has {len(value)} characters; max_detail_len={limits.max_detail_len}"
            raise WireError(msg, ErrorCode.LIMIT_EXCEEDED, "max_detail_len")

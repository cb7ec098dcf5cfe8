"""lessmap wire contract: key expressions, messages and their msgpack codec.

Imports only pydantic, msgpack and the standard library, so any robot or fleet app can depend
on it without zenoh or numpy. The language-neutral specification is `schemas/README.md`.
"""

from __future__ import annotations

from importlib.metadata import version

from lessmap_schemas import keys
from lessmap_schemas.codec import MEDIA_TYPE, decode, decode_inbound, encode, encoding
from lessmap_schemas.errors import ErrorCode, InvalidNameError, WireError
from lessmap_schemas.keys import KEY_PREFIX, WIRE_VERSION, validate_name
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits
from lessmap_schemas.messages import (
    MESSAGE_TYPES,
    AreaGraph,
    Error,
    Frame,
    Health,
    Message,
    SessionEnd,
    SessionState,
    Submap,
    SubmapSummary,
    Transition,
)

__version__ = version("lessmap-schemas")  # one source: the repository's VERSION file

__all__ = [
    "DEFAULT_LIMITS",
    "KEY_PREFIX",
    "MEDIA_TYPE",
    "MESSAGE_TYPES",
    "WIRE_VERSION",
    "AreaGraph",
    "Error",
    "ErrorCode",
    "Frame",
    "Health",
    "InvalidNameError",
    "Message",
    "SessionEnd",
    "SessionState",
    "Submap",
    "SubmapSummary",
    "Transition",
    "WireError",
    "WireLimits",
    "__version__",
    "decode",
    "decode_inbound",
    "encode",
    "encoding",
    "keys",
    "validate_name",
]

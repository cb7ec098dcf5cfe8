"""Errors raised on bytes and names that break the wire contract.

A `WireError` always means "drop this sample, count it, go on": it is raised for remote input,
never for a bug on the local side. Its `code` is what the service publishes in an `Error`
message, so every failure a reader can hit maps to exactly one `ErrorCode`.
"""

from __future__ import annotations

from enum import StrEnum


class ErrorCode(StrEnum):
    """Why a message was rejected or a frame was not applied (the `code` of an `Error`)."""

    MALFORMED = "MALFORMED"
    """Not msgpack, truncated, trailing bytes, or the top level is not a map with string keys."""
    INVALID = "INVALID"
    """A well-formed map that breaks the schema: missing, extra or mistyped field, bad range."""
    UNKNOWN_TYPE = "UNKNOWN_TYPE"
    """The `type` field is missing, unknown, or names a message not accepted on this key."""
    UNSUPPORTED_VERSION = "UNSUPPORTED_VERSION"
    """The `v` field is missing or is not a version this reader speaks (1)."""
    BAD_NAME = "BAD_NAME"
    """A fleet, robot, session or instance name, or a key expression, breaks the name rule."""
    LIMIT_EXCEEDED = "LIMIT_EXCEEDED"
    """A size limit was hit: payload bytes, features per frame, list length, seq, feature id."""
    DUPLICATE_SEQ = "DUPLICATE_SEQ"
    """The frame's seq is not above the last applied one: a retransmission, ignored."""
    OUT_OF_ORDER = "OUT_OF_ORDER"
    """The frame arrived after a later frame was applied (its slot was counted missing)."""
    SEQ_GAP = "SEQ_GAP"
    """Frames between the last applied seq and this one never arrived; processing went on."""
    SESSION_LIMIT = "SESSION_LIMIT"
    """The service holds as many sessions as it is configured for; the frame was dropped."""
    GRAPH_LIMIT = "GRAPH_LIMIT"
    """The session's CovGraph reached its configured size; the frame was dropped."""
    SESSION_CLOSED = "SESSION_CLOSED"
    """A frame or SessionEnd arrived for a session that a SessionEnd already closed."""
    INTERNAL = "INTERNAL"
    """The service failed on valid input (a bug); the session was reset."""
    DURABILITY_LOST = "DURABILITY_LOST"
    """The service's state store stopped taking checkpoints; it keeps them in memory, retries."""
    DURABILITY_BACK = "DURABILITY_BACK"
    """The state store takes checkpoints again; every open session was checkpointed anew."""


class WireError(ValueError):
    """Wire Error: remote bytes or names that break the contract.

    Attributes:
        code: The error code a service reports for this failure.
        limit: Name of the `WireLimits` field that was exceeded, if a limit caused it.
    """

    def __init__(
        self, msg: str, code: ErrorCode = ErrorCode.INVALID, limit: str | None = None
    ) -> None:
        super().__init__(msg)
        self.code = code
        self.limit = limit

    def __reduce__(self) -> tuple[type[Exception], tuple[object, ...]]:
        # Exception pickles only `args`; keep code and limit across process boundaries.
        return (type(self), (str(self), self.code, self.limit))


class InvalidNameError(WireError):
    """Invalid Name Error: a name or key expression breaks the name rule (code BAD_NAME)."""

    def __init__(self, msg: str, limit: str | None = None) -> None:
        super().__init__(msg, ErrorCode.BAD_NAME, limit)

    def __reduce__(self) -> tuple[type[Exception], tuple[object, ...]]:
        return (InvalidNameError, (str(self), self.limit))


class FramesFileError(ValueError):
    """Frames File Error: a line of a frames file is malformed (the message names FILE:LINE)."""

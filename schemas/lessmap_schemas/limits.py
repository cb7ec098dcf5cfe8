"""Size limits of the wire contract, shared by every reader and writer.

Two kinds of limits live here:

* Receiver policy (`max_payload_bytes`, `max_features_per_frame`, `max_list_len`): how much a
  reader is willing to accept. A service may raise or lower them (`LESSMAP_LIMITS__<NAME>`).
* Format bounds (`max_name_len`, `max_seq`, `max_feature_id`, `max_detail_len`): part of the
  format itself, fixed in the models and the JSON Schemas so every language agrees. A reader may
  tighten them, never loosen them: a longer name or a larger seq would not be the format any more.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

MAX_NAME_LEN = 64
"""Format bound: longest fleet, robot, session or instance name."""
MAX_SEQ = 2**53 - 1
"""Format bound: largest seq; the largest integer a JavaScript number holds exactly."""
MAX_FEATURE_ID = 2**63 - 1
"""Format bound: largest feature ID; fits a signed 64-bit integer in every language."""
MAX_DETAIL_LEN = 1024
"""Format bound: longest `Error.detail`; also the longest string any message may carry."""

_FORMAT_BOUNDS = {
    "max_name_len": MAX_NAME_LEN,
    "max_seq": MAX_SEQ,
    "max_feature_id": MAX_FEATURE_ID,
    "max_detail_len": MAX_DETAIL_LEN,
}


@dataclass(frozen=True, slots=True, kw_only=True)
class WireLimits:
    """Bounds a reader enforces on every decoded message.

    Attributes:
        max_payload_bytes: Largest encoded message, checked before unpacking anything.
        max_features_per_frame: Longest `Frame.features` list (duplicates count).
        max_name_len: Longest name (format bound, may only be lowered).
        max_seq: Largest seq, first_seq, last_seq, boundary_seq or incarnation (format bound).
        max_feature_id: Largest feature ID (format bound).
        max_detail_len: Longest `Error.detail` (format bound).
        max_list_len: Longest list in a service-to-client message (submap features,
            closed submaps, boundary features).
    """

    max_payload_bytes: int = 1_048_576
    max_features_per_frame: int = 4096
    max_name_len: int = MAX_NAME_LEN
    max_seq: int = MAX_SEQ
    max_feature_id: int = MAX_FEATURE_ID
    max_detail_len: int = MAX_DETAIL_LEN
    max_list_len: int = 100_000

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if type(value) is not int or value < 1:
                msg = f"WireLimits.{field.name} must be a positive int, not {value!r}"
                raise ValueError(msg)
            bound = _FORMAT_BOUNDS.get(field.name)
            if bound is not None and value > bound:
                msg = f"WireLimits.{field.name}={value} loosens the format bound {bound}"
                raise ValueError(msg)

    @property
    def tightens_format(self) -> bool:
        """Return whether any format bound is lower than the format fixes it."""
        return any(getattr(self, name) < bound for name, bound in _FORMAT_BOUNDS.items())


DEFAULT_LIMITS = WireLimits()
"""The limits every reader uses unless told otherwise."""

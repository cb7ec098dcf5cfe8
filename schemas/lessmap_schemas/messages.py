"""Messages of the lessmap wire contract: the source of truth for schemas and vectors.

Invariants every model keeps (the README and the JSON Schemas are generated from or checked
against these models, so change them here first):

* `type` and `v` are the first two fields, so any reader can dispatch before it knows the rest.
* Field order is the canonical msgpack key order; `codec.encode` writes fields in this order.
* Models are frozen, reject unknown fields and are strict: `"5"` is not an int, `True` is not
  an int, `5.0` is not an int. Float fields accept ints, because JavaScript encoders write
  `5.0` as the integer 5.
* Format bounds (name length, seq, feature id, detail length) are fixed here; receiver-policy
  limits (payload size, list lengths) live in `WireLimits` and are enforced by the codec.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Annotated, Literal, Self

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    StringConstraints,
    model_validator,
)

from lessmap_schemas.errors import ErrorCode, InvalidNameError, WireError
from lessmap_schemas.keys import NAME_PATTERN
from lessmap_schemas.limits import MAX_DETAIL_LEN, MAX_FEATURE_ID, MAX_NAME_LEN, MAX_SEQ
from lessmap_schemas.partition import PARTITIONS

__all__ = [
    "MESSAGE_TYPES",
    "AreaGraph",
    "AreaNode",
    "Epoch",
    "Error",
    "ErrorCode",
    "FeatureId",
    "Frame",
    "Health",
    "InvalidNameError",
    "Message",
    "Method",
    "Name",
    "PartitionId",
    "Passage",
    "Seq",
    "SessionEnd",
    "SessionState",
    "Submap",
    "SubmapSummary",
    "Transition",
    "WireError",
]

Name = Annotated[
    str, StringConstraints(min_length=1, max_length=MAX_NAME_LEN, pattern=NAME_PATTERN)
]
"""Fleet, robot, session or instance name (see `keys.validate_name`)."""
Seq = Annotated[int, Field(ge=0, le=MAX_SEQ)]
"""Frame sequence number: 0 <= seq <= 2**53-1, so JavaScript numbers hold it exactly."""
Count = Annotated[int, Field(ge=0, le=MAX_SEQ)]
"""Non-negative counter, JavaScript-safe."""
Epoch = Annotated[int, Field(ge=1, le=MAX_SEQ)]
"""Ownership epoch of a partition: grows each time the partition gets a new owner."""
PartitionId = Annotated[int, Field(ge=0, lt=PARTITIONS)]
"""Partition of a robot (see `partition.partition_of`)."""
FeatureId = Annotated[int, Field(ge=0, le=MAX_FEATURE_ID)]
"""Feature ID: 0 <= id <= 2**63-1 (a signed 64-bit integer)."""
Finite = Annotated[float, Field(allow_inf_nan=False)]
"""Finite float64; NaN and infinities are rejected."""
Pose = Annotated[tuple[Finite, Finite, Finite], Strict(False)]
"""(x_m, y_m, theta_rad). Lax only on the container: msgpack arrays decode as lists."""
Method = Literal["paper", "areas"]
"""Segmentation method of a session: the paper's LESS-mapping, or areas (revisits named)."""


def _error_code(value: object) -> object:
    # Strict enums take only members; the wire carries the value as a msgpack str.
    if type(value) is str and value in ErrorCode.__members__:
        return ErrorCode(value)
    return value


_CONFIG = ConfigDict(frozen=True, extra="forbid", strict=True, use_attribute_docstrings=True)


class Message(BaseModel):
    """Base of every top-level message: `type` names the model, `v` the wire version."""

    model_config = _CONFIG

    type: str
    v: int


class Frame(Message):
    """One sensor frame of a robot session: the features it observed (robot -> service)."""

    type: Literal["Frame"] = "Frame"
    v: Literal[4] = 4
    session: Name
    """Robot-chosen session id; a restarted robot picks a new one and gets a new CovGraph."""
    seq: Seq
    """Frame number, strictly increasing within the session; 0 <= seq <= 2**53-1."""
    stamp_s: Finite
    """Acquisition time in seconds, any epoch (the robot's clock)."""
    features: list[FeatureId]
    """IDs of the features observed; duplicates count once; may be empty."""
    pose: Pose | None = None
    """Optional planar pose (x_m, y_m, theta_rad) in the robot's odometry frame."""


class SessionEnd(Message):
    """The robot ends its session; the service closes it (robot -> service, on `frames`)."""

    type: Literal["SessionEnd"] = "SessionEnd"
    v: Literal[4] = 4
    session: Name
    """Session being ended."""
    last_seq: Seq | None
    """Seq of the last frame the robot sent, or null if it sent none."""
    stamp_s: Finite
    """Time of the end in seconds, the robot's clock."""


class SubmapSummary(BaseModel):
    """A submap: the frames of one area and the features seen in it (nested only)."""

    model_config = _CONFIG

    id: Count
    """Submap id, 0 for the first submap of a session, +1 per transition."""
    first_seq: Seq
    """Seq of the first frame of the submap."""
    last_seq: Seq
    """Seq of the last frame of the submap so far; first_seq <= last_seq."""
    frame_count: Count
    """Frames applied to the submap (gaps make it smaller than last_seq - first_seq + 1)."""
    features: list[FeatureId]
    """Distinct feature IDs seen in the submap, in ascending order."""

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if self.first_seq > self.last_seq:
            msg = f"first_seq {self.first_seq} is after last_seq {self.last_seq}"
            raise ValueError(msg)
        return self


class Transition(Message):
    """The robot left one area for another (service -> apps)."""

    type: Literal["Transition"] = "Transition"
    v: Literal[4] = 4
    fleet: Name
    """Fleet of the robot."""
    robot: Name
    """Robot that moved."""
    session: Name
    """Session the frames belong to."""
    incarnation: Seq
    """First seq of the history the decision stands on (0 when nothing was lost); a new
    value after state was lost. Identity: (fleet, robot, session, incarnation, closed.id)."""
    seq: Seq
    """Detection frame: the last frame covered by this decision."""
    boundary_seq: Seq
    """Estimated first frame in the new area; boundary_seq <= seq."""
    stamp_s: Finite
    """Stamp of the detection frame, in seconds (the robot's clock)."""
    reason: Literal["SPECTRAL", "DISCONNECTED", "RECOGNISED"]
    """SPECTRAL: a normalized cut below threshold; DISCONNECTED: the CovGraph fell apart;
    RECOGNISED: the last frames fit an area the robot mapped before (method `areas`)."""
    ncut: Finite | None
    """Normalized cut of the accepted split; null unless the reason is SPECTRAL."""
    lambda2: Finite | None
    """Second smallest generalized eigenvalue (algebraic connectivity); null unless SPECTRAL."""
    closed: SubmapSummary
    """The submap left behind; final."""
    opened: SubmapSummary
    """The submap entered, with its frames so far."""
    boundary_features: list[FeatureId]
    """Features seen on both sides of the boundary, ascending."""
    area: Count
    """Area entered: the id of the `AreaGraph` node the opened submap belongs to."""
    left_area: Count
    """Area left: the id of the area the closed submap belongs to; never equal to `area`."""
    revisit: bool
    """True when the robot mapped the area entered before in this session (method `areas`)."""
    batch_frames: Annotated[int, Field(ge=1, le=MAX_SEQ)]
    """Frames covered by this decision; above 1 when the service coalesced frames under load."""
    instance: Name
    """Service instance that produced the transition."""
    partition: PartitionId
    """Partition of the robot."""
    epoch: Epoch
    """Ownership epoch of the partition at the instance that produced it (fencing)."""

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        if self.boundary_seq > self.seq:
            msg = f"boundary_seq {self.boundary_seq} is after seq {self.seq}"
            raise ValueError(msg)
        if self.incarnation > self.closed.first_seq:
            msg = (
                f"incarnation {self.incarnation} is after closed.first_seq {self.closed.first_seq}"
            )
            raise ValueError(msg)
        spectral = self.reason == "SPECTRAL"
        if (self.ncut is not None) != spectral or (self.lambda2 is not None) != spectral:
            msg = f"{self.reason}: ncut, lambda2 are set for SPECTRAL only, null otherwise"
            raise ValueError(msg)
        if self.area == self.left_area:
            msg = f"area {self.area} equals left_area: a transition changes area"
            raise ValueError(msg)
        return self


class Error(Message):
    """A frame or message was rejected, or frames went missing (service -> apps)."""

    type: Literal["Error"] = "Error"
    v: Literal[4] = 4
    fleet: Name | None
    """Fleet of the key the input arrived on; null if the key could not be parsed."""
    robot: Name | None
    """Robot of the key the input arrived on; null if the key could not be parsed."""
    session: Name | None
    """Session of the offending input; null if it could not be decoded."""
    code: Annotated[ErrorCode, BeforeValidator(_error_code)]
    """What went wrong (see ErrorCode)."""
    detail: Annotated[str, StringConstraints(max_length=MAX_DETAIL_LEN)]
    """Human-readable explanation, at most 1024 characters."""
    seq: Seq | None
    """Seq of the offending frame, if known."""
    stamp_s: Finite
    """When the service saw the problem, in seconds since the Unix epoch (service clock)."""
    instance: Name
    """Service instance that reports the error."""
    epoch: Epoch | None
    """Ownership epoch of the robot's partition at that instance; null if unattributable."""


class SessionState(Message):
    """Counters and submaps of a robot's current session (reply to a `state` query)."""

    type: Literal["SessionState"] = "SessionState"
    v: Literal[4] = 4
    fleet: Name
    """Fleet of the robot."""
    robot: Name
    """Robot of the session."""
    session: Name
    """The robot's current (latest) session."""
    incarnation: Seq
    """First seq of the history the service holds (0 when nothing was lost): submap and
    area ids of this reply belong to it."""
    instance: Name
    """Service instance holding the session."""
    epoch: Epoch
    """Ownership epoch of the robot's partition at that instance."""
    open: bool
    """False once a SessionEnd closed the session."""
    last_seq: Seq | None
    """Seq of the last frame applied; null before the first frame."""
    frames_applied: Count
    """Frames applied to the CovGraph, in seq order, each once."""
    frames_duplicate: Count
    """Frames ignored because their seq was not above the last received one (late ones too)."""
    frames_missing: Count
    """Frames never received: the sum of all seq gaps (late arrivals stay counted here)."""
    frames_rejected: Count
    """Frames received in order but refused (limits, invalid content)."""
    transitions: Count
    """Transitions published for this session."""
    method: Method
    """Segmentation method of the session: `paper` (LESS-mapping as published) or `areas`."""
    current_area: Count
    """Area the robot is in (an `AreaGraph` node id)."""
    current_submap: SubmapSummary
    """The submap the robot is in."""
    closed_submaps: list[SubmapSummary]
    """Submaps left behind, oldest first."""
    nodes: Count
    """Nodes in the session's CovGraph."""
    edges: Count
    """Edges in the session's CovGraph."""


class Submap(Message):
    """One submap of a robot's session (reply to a `submaps/<id>` query)."""

    type: Literal["Submap"] = "Submap"
    v: Literal[4] = 4
    fleet: Name
    """Fleet of the robot."""
    robot: Name
    """Robot of the session."""
    session: Name
    """Session the submap belongs to."""
    summary: SubmapSummary
    """Frames and features of the submap."""
    open: bool
    """True for the submap the robot is in (it still grows)."""


class AreaNode(BaseModel):
    """One area of a robot's session: a node of its `AreaGraph` (nested only)."""

    model_config = _CONFIG

    id: Count
    """Area id within the session, from 0 in order of opening; a merged id is not reused."""
    frames: Count
    """Frames the robot spent in the area, over all its visits."""
    visits: Annotated[int, Field(ge=1, le=MAX_SEQ)]
    """Separate stays in the area."""
    first_seq: Seq
    """First frame in the area."""
    last_seq: Seq
    """Last frame in the area so far; first_seq <= last_seq."""
    features: list[FeatureId]
    """Distinct feature IDs of the area, ascending."""

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if self.first_seq > self.last_seq:
            msg = f"first_seq {self.first_seq} is after last_seq {self.last_seq}"
            raise ValueError(msg)
        return self


BoundaryCount = Annotated[tuple[FeatureId, Count], Strict(False)]
"""(feature ID, passages that reported it). Lax only on the container, like `Pose`."""


class Passage(BaseModel):
    """The robot's passages between two areas `a < b`: an edge of its `AreaGraph`."""

    model_config = _CONFIG

    a: Count
    """Lower area id."""
    b: Count
    """Higher area id; a < b."""
    a_to_b: Count
    """Passages from a to b."""
    b_to_a: Count
    """Passages from b to a."""
    boundary_features: list[BoundaryCount]
    """Most reported boundary features of these passages, most frequent first (ties: smaller
    id); at most 16, and trimmed counts are lower bounds."""

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if self.a >= self.b:
            msg = f"passage a={self.a} must be below b={self.b}"
            raise ValueError(msg)
        if self.a_to_b + self.b_to_a == 0:
            msg = f"passage {self.a}-{self.b} counts no passage"
            raise ValueError(msg)
        return self


class AreaGraph(Message):
    """A robot session's areas and the passages between them (reply to an `areas` query)."""

    type: Literal["AreaGraph"] = "AreaGraph"
    v: Literal[4] = 4
    fleet: Name
    """Fleet of the robot."""
    robot: Name
    """Robot of the session."""
    session: Name
    """Session the areas belong to (the robot's current one)."""
    instance: Name
    """Service instance holding the session."""
    epoch: Epoch
    """Ownership epoch of the robot's partition at that instance."""
    method: Method
    """Segmentation method of the session; under `paper` every submap is its own area."""
    areas: list[AreaNode]
    """Areas by ascending id."""
    passages: list[Passage]
    """Passages by ascending (a, b); every a and b is the id of a listed area."""

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        ids = [area.id for area in self.areas]
        if any(later <= earlier for earlier, later in pairwise(ids)):
            msg = "areas must be listed by strictly ascending id"
            raise ValueError(msg)
        known = set(ids)
        for passage in self.passages:
            if passage.a not in known or passage.b not in known:
                msg = f"passage {passage.a}-{passage.b} names an area that is not listed"
                raise ValueError(msg)
        pairs = [(p.a, p.b) for p in self.passages]
        if any(later <= earlier for earlier, later in pairwise(pairs)):
            msg = "passages must be listed by strictly ascending (a, b)"
            raise ValueError(msg)
        return self


class Health(Message):
    """Liveness figures of one service instance (reply to a `health` query)."""

    type: Literal["Health"] = "Health"
    v: Literal[4] = 4
    instance: Name
    """The instance reporting."""
    version: Annotated[str, StringConstraints(min_length=1, max_length=MAX_NAME_LEN)]
    """Service software version, e.g. "0.1.0"."""
    sessions: Count
    """Sessions held in memory."""
    uptime_s: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    """Seconds since the instance started."""
    frames_applied: Count
    """Frames applied over all sessions since start."""
    partitions: list[PartitionId]
    """Partitions this instance owns, ascending."""
    standby: list[PartitionId]
    """Partitions this instance is the standby of, ascending."""
    queue_depth: Count
    """Messages received and not yet handled."""
    lag_s: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    """Age of the oldest message not yet handled, in seconds (0 when none waits)."""


MESSAGE_TYPES: dict[str, type[Message]] = {
    model.__name__: model
    for model in (Frame, SessionEnd, Transition, Error, SessionState, Submap, AreaGraph, Health)
}
"""Every top-level message by its `type` value."""

"""The records a session table keeps and returns: sessions, outcomes, refusals, catch-ups."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lessmap.runtime.sessions.seq import RobotKey, SeqState

if TYPE_CHECKING:
    from lessmap.core.segmenter import SegmentChange, Segmenter
    from lessmap.runtime.record import SessionRecord
    from lessmap_schemas.errors import ErrorCode
    from lessmap_schemas.messages import AreaGraph, Frame, SessionEnd, SessionState

# Cost units of the fair scheduler (shard.py): roughly one pair update each. A frame costs
# its pairs plus a fixed overhead; a decision costs in proportion to the CovGraph's edges
# (docs/tuning/scheduler.md).
FRAME_COST = 1000
DECISION_COST_PER_EDGE = 10


@dataclass(frozen=True, slots=True)
class Rejection:
    """An inbound message the table refused, and why (becomes an Error event)."""

    fleet: str
    robot: str
    session: str | None
    code: ErrorCode
    detail: str
    seq: int | None


@dataclass(frozen=True, slots=True)
class CatchupRequest:
    """Ask a robot's publication cache for its newest frames (the shard sends the query)."""

    fleet: str
    robot: str
    session: str
    after_seq: int  # the last seq received in order: the frames after it are wanted
    max_frames: int


@dataclass(slots=True)
class RobotSession(SeqState):
    """One robot session: its seq counters, its segmenter (paper or areas), its schedules."""

    fleet: str
    robot: str
    session: str
    segmenter: Segmenter
    last_activity_s: float
    frames_since_checkpoint: int = 0
    checkpoint_s: float = 0.0  # activity time of the last checkpoint
    # Catch-up (``catchup.py``): frames beyond a gap, waiting for the robot's cache to fill it.
    held: dict[int, Frame] = field(default_factory=dict)
    held_end: SessionEnd | None = None  # an end that arrived during the hold
    hold_until_s: float | None = None  # a hold is under way until then
    next_catchup_s: float = 0.0  # no new catch-up query before
    recovered: int = 0  # frames the current hold took from the robot's cache
    edges: int = 0  # upper bound of the CovGraph's edges (exact after a decision)
    fenced: bool = False  # a transition of it was not published: never checkpointed

    @property
    def key(self) -> RobotKey:
        """(fleet, robot)."""
        return (self.fleet, self.robot)


@dataclass(slots=True)
class Outcome:
    """What one batch produced, for the transport layer to publish."""

    transitions: list[tuple[RobotSession, SegmentChange]] = field(default_factory=list)
    rejections: list[Rejection] = field(default_factory=list)
    opened: list[RobotSession] = field(default_factory=list)
    resumed: list[RobotSession] = field(default_factory=list)  # restored from the store
    closed: list[tuple[SessionState, str]] = field(default_factory=list)  # (final state, cause)
    suspended: list[SessionState] = field(default_factory=list)  # checkpointed at stop
    evicted: int = 0  # idle sessions moved to the store
    frames_applied: int = 0
    frames_duplicate: int = 0
    frames_missing: int = 0
    frames_late: int = 0  # OUT_OF_ORDER: counted missing when the gap was seen, now rejected
    decisions: list[tuple[float, int]] = field(default_factory=list)  # (seconds, batch frames)
    catchups: list[CatchupRequest] = field(default_factory=list)  # queries for the shard
    frames_recovered: int = 0  # taken from a robot's cache and applied or held
    failures: list[tuple[RobotKey, Exception]] = field(default_factory=list)
    # Records to save once the rest was published (``durability.commit_checkpoints``).
    checkpoints: list[tuple[RobotSession, SessionRecord]] = field(default_factory=list)

    def reject(
        self,
        fleet: str,
        robot: str,
        session: str | None,
        code: ErrorCode,
        detail: str,
        seq: int | None,
    ) -> None:
        """Record a refused (or, for SEQ_GAP, a noted) message."""
        self.rejections.append(Rejection(fleet, robot, session, code, detail, seq))


@dataclass(frozen=True, slots=True)
class MovedRobot:
    """What a session table keeps of one robot, handed whole to another table."""

    key: RobotKey
    session: RobotSession | None  # its open session, if any
    closed_ids: list[str]
    final_state: SessionState | None
    final_graph: AreaGraph | None

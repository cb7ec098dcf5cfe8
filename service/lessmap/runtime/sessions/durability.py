"""Durable sessions: the checkpoint schedule, the records, resuming, what the store answers.

Invariants (with a ``CheckpointStore`` that reaches a file):

1. A session is checkpointed every ``every_frames`` applied frames or ``interval_s``,
   whichever comes first, when it closes and when the service stops.
2. A session not in memory is looked up in the store on its next frame and resumes exactly
   where its checkpoint stands (the segmenter's bytes, its counters and gap ranges).
3. Idle sessions are evicted to the store instead of being closed (without a file they
   close); a full shard evicts those idle ``EVICT_MIN_IDLE_S`` or more, longest idle first.
   Without a file, a hand-over still checkpoints: the store's memory shelf carries the
   records to the new owner, which resumes them as with a file (``resumes``).
4. The table never saves a checkpoint: it travels in the outcome and ``commit_checkpoints``
   saves it after the outcome was published, so no checkpoint (kept, shipped, answered)
   covers a transition that is not on the wire yet, and none of a session with a fenced
   transition (``RobotSession.fenced``): the partition's next owner decides those anew.
"""

from __future__ import annotations

import logging
import sqlite3
import zlib
from typing import TYPE_CHECKING, Any

from lessmap.core import GraphError
from lessmap.core.segmenter import segmenter_from_bytes
from lessmap.runtime.record import SessionRecord
from lessmap.runtime.sessions.model import RobotSession
from lessmap.runtime.sessions.wire import session_state, wire_area_graph
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.keys import WIRE_VERSION
from lessmap_schemas.messages import AreaGraph, Frame, SessionEnd, SessionState

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from lessmap.runtime.sessions.model import Outcome
    from lessmap.runtime.sessions.policy import DurabilityPolicy, Identity
    from lessmap.runtime.sessions.seq import ClosedIds, RobotKey
    from lessmap.runtime.store import CheckpointStore

log = logging.getLogger(__name__)

EVICT_MIN_IDLE_S = 1.0  # a full shard evicts sessions idle this long to admit a new one
EVICT_BATCH = 16  # sessions evicted at once when the shard is full (amortizes the scan)


def commit_checkpoints(outcome: Outcome, store: CheckpointStore) -> int:
    """Save an outcome's checkpoints (invariant 4); call it once the outcome was published.

    Returns how many were withheld: those of sessions with a transition the fence held back.
    """
    withheld = 0
    for session, record in outcome.checkpoints:
        if session.fenced:
            withheld += 1
        else:
            store.save(record)
    outcome.checkpoints.clear()  # committed once, even if published again
    return withheld


class Durability:
    """Checkpoints of one table's sessions; without a file, a no-op that resumes nothing."""

    def __init__(
        self,
        store: CheckpointStore | None,
        policy: DurabilityPolicy,
        identity: Identity,
        wall_clock: Callable[[], float],
    ) -> None:
        self.store = store if store is not None and store.path is not None else None
        # Where sessions resume from: the file, or without one the hand-over shelf.
        self._source = store
        self._policy = policy
        self._identity = identity
        self._wall_clock = wall_clock

    @property
    def resumes(self) -> bool:
        """True when a session not in memory may have a record to resume from."""
        return self._source is not None

    def phase(self, session: RobotSession, now_s: float) -> None:
        """Start a session's checkpoint clock at a phase of its own.

        Robots of a fleet usually start together and run at one rate: without a phase, all
        their checkpoints fall due in the same instant, a burst of snapshots on the worker
        (docs/tuning/checkpoints.md). The phase comes from the robot's name (crc32), so it
        is the same in every run; the first checkpoint of a session comes that much
        earlier, later ones keep the spacing.
        """
        policy = self._policy
        phase = 0.0
        if policy.phased:
            phase = zlib.crc32(f"{session.fleet}/{session.robot}".encode()) / 2**32
        session.frames_since_checkpoint = int(phase * policy.every_frames)
        session.checkpoint_s = now_s - phase * policy.interval_s

    def due(self, session: RobotSession, now_s: float) -> bool:
        """True when the session's next checkpoint is due (invariant 1)."""
        policy = self._policy
        return self.store is not None and (
            session.frames_since_checkpoint >= policy.every_frames
            or (
                session.frames_since_checkpoint > 0
                and now_s - session.checkpoint_s >= policy.interval_s
            )
        )

    def record(
        self,
        session: RobotSession,
        status: str,
        closed_ids: list[str],
        *,
        final: tuple[SessionState, AreaGraph] | None = None,
    ) -> SessionRecord:
        """The session's record for the store; a closed one's with its ``final`` state and graph.

        A closed session keeps no snapshot: its final state and area graph are stored for
        queries instead. Other records hold no state: ``stored_state`` makes it from the
        snapshot when asked, rather than every checkpoint writing up to 1,000 closed
        segments twice.
        """
        kept: dict[str, Any] = {}
        if final is not None:
            kept["state"] = final[0].model_dump(mode="json")
            kept["area_graph"] = final[1].model_dump(mode="json")
        return SessionRecord(
            fleet=session.fleet,
            robot=session.robot,
            session=session.session,
            status=status,
            last_seq=session.last_seen_seq,
            meta={
                **session.counters(),
                "closed_ids": closed_ids,
                "epoch": self._identity.epoch_of(session.fleet, session.robot),
                **kept,
            },
            snapshot=session.segmenter.to_bytes() if final is None else None,
            updated_s=self._wall_clock(),
        )

    def checkpoint(
        self, session: RobotSession, status: str, now_s: float, out: Outcome, closed: ClosedIds
    ) -> None:
        """Put the session's record in the outcome and restart its checkpoint clock."""
        record = self.record(session, status, closed.of(session.key))
        out.checkpoints.append((session, record))
        session.frames_since_checkpoint = 0
        session.checkpoint_s = now_s

    def resume(
        self, key: RobotKey, out: Outcome, now_s: float, closed: ClosedIds
    ) -> RobotSession | None:
        """The robot's checkpointed session, back from the store, if it has an open one."""
        source = self._source
        assert source is not None
        fleet, robot = key
        # A record of this outcome is not saved yet (an eviction earlier in the same batch).
        record = next((r for _s, r in reversed(out.checkpoints) if r.key == key), None)
        try:
            if record is None:
                record = source.load(key)
        except sqlite3.Error as exc:
            out.reject(
                fleet, robot, None, ErrorCode.INTERNAL, f"state store unreadable: {exc}", None
            )
            return None
        if record is None:
            return None
        closed.remember(key, record.meta.get("closed_ids", ()))
        if record.status == "closed":
            closed.remember(key, [record.session])
            return None
        if (key, record.session) in closed:
            # An open record of a session known closed is stale: the store can hand back an
            # older row while its writer holds the newest batch. Reopening it would apply a
            # straggler to a closed session and overwrite its final state.
            log.debug("stale open record of closed session %s/%s %s", fleet, robot, record.session)
            return None
        try:
            assert record.snapshot is not None, "an open record without a snapshot"
            segmenter = segmenter_from_bytes(record.snapshot)
            session = RobotSession(fleet, robot, record.session, segmenter, now_s)
            session.restore_counters(record.meta)
        except Exception as exc:  # a damaged checkpoint must cost only its own session
            log.error("checkpoint of %s/%s %s unreadable: %s", fleet, robot, record.session, exc)
            out.reject(
                fleet,
                robot,
                record.session,
                ErrorCode.INTERNAL,
                f"checkpoint unreadable ({type(exc).__name__}); the session starts fresh",
                None,
            )
            source.delete(key)
            return None
        source.resumed(key)
        self.phase(session, now_s)
        return session

    # -- what the store answers for robots not in memory ---------------------------------

    def _load(self, key: RobotKey) -> SessionRecord | None:
        if self._source is None:
            return None
        try:
            return self._source.load(key)
        except sqlite3.Error:
            return None

    def stored_state(self, key: RobotKey) -> SessionState | None:
        """The state a robot's record holds, if any."""
        record = self._load(key)
        if record is None:
            return None
        if "state" in record.meta:  # closed, or written before open records left it out
            return SessionState.model_validate(current_version(record.meta["state"], incarnation=0))
        if record.snapshot is None:
            return None
        fleet, robot = key
        try:  # an evicted or handed-over session: its state is in its snapshot and counters
            session = RobotSession(
                fleet, robot, record.session, segmenter_from_bytes(record.snapshot), 0.0
            )
            session.restore_counters(record.meta)
        except (GraphError, KeyError, TypeError, ValueError) as exc:
            log.warning("checkpoint of %s/%s unreadable for its state: %s", fleet, robot, exc)
            return None
        epoch = int(record.meta.get("epoch", 1))
        return session_state(session, self._identity.instance, is_open=True, epoch=epoch)

    def stored_area_graph(self, key: RobotKey) -> AreaGraph | None:
        """The area graph of a robot's record: a closed one's, or an evicted one's snapshot."""
        record = self._load(key)
        if record is None:
            return None
        if "area_graph" in record.meta:  # closed
            return AreaGraph.model_validate(current_version(record.meta["area_graph"]))
        if record.snapshot is None:
            return None
        fleet, robot = key
        try:  # an evicted session: its graph is in its snapshot
            segmenter = segmenter_from_bytes(record.snapshot)
        except GraphError as exc:
            log.warning("checkpoint of %s/%s unreadable for its areas: %s", fleet, robot, exc)
            return None
        return wire_area_graph(
            fleet,
            robot,
            record.session,
            segmenter.area_graph(),
            method=segmenter.method.wire,
            instance=self._identity.instance,
            epoch=self._identity.epoch_of(fleet, robot),
        )

    def stored_news(self, key: RobotKey, message: Frame | SessionEnd) -> bool:
        """``SessionTable.is_news`` for a robot not in memory, judged on its record."""
        record = self._load(key)
        if record is None or record.session != message.session:
            return isinstance(message, Frame)
        if record.status == "closed":
            return False
        if isinstance(message, SessionEnd):
            return True
        return record.last_seq is None or message.seq > record.last_seq


def current_version(message: dict[str, Any], **added: object) -> dict[str, Any]:
    """A message a record kept, as this contract version writes it.

    Records outlive upgrades: a message kept under an older contract lacks the fields added
    since, given here with the value they mean for it (``added``).
    """
    return {**added, **message, "v": WIRE_VERSION}


def evictable(sessions: Iterable[tuple[RobotKey, RobotSession]], now_s: float) -> list[RobotKey]:
    """Sessions a full shard may evict (invariant 3): longest idle first, none busy."""
    found: list[RobotKey] = []
    for key, session in sessions:
        if len(found) >= EVICT_BATCH or now_s - session.last_activity_s < EVICT_MIN_IDLE_S:
            break
        found.append(key)
    return found

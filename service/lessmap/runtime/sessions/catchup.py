"""Catch-up holds: frames beyond a gap wait while the robot's publication cache is asked.

Invariants (``CatchupPolicy.max_frames > 0``; the service turns it on with a store):

1. A frame beyond a gap is held, with every later frame of the session, and the outcome
   asks the robot's cache for its newest ``max_frames`` frames; recovered and late live
   frames fill the hold, whatever is contiguous is applied in seq order at once.
2. When the cache has answered, after ``wait_s``, or past ``max_frames`` held frames, the
   hold is released: held frames are applied in seq order, only seqs nobody returned are
   reported as SEQ_GAP.
3. A ``SessionEnd`` beyond the last seen frame starts a catch-up too (once) and waits for
   it, so a tail dropped at a former owner during a hand-over is recovered.
4. One catch-up per session at a time, at most one per ``wait_s``; unneeded recovered
   frames are dropped silently; held frames are not in a checkpoint.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from lessmap.runtime.sessions.model import CatchupRequest
from lessmap_schemas.errors import ErrorCode

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from lessmap.runtime.sessions.model import Outcome, RobotSession
    from lessmap.runtime.sessions.policy import CatchupPolicy
    from lessmap.runtime.sessions.seq import CacheMarks, RobotKey
    from lessmap_schemas.messages import Frame

log = logging.getLogger(__name__)


def tail_awaited(session: RobotSession) -> bool:
    """True while a held end names frames not seen yet: the cache's reply may bring more."""
    end = session.held_end
    seen = session.last_seen_seq
    if end is None or end.last_seq is None:
        return False
    return seen is None or seen < end.last_seq


class Holds:
    """The sessions of one table that hold frames for a catch-up."""

    def __init__(self, policy: CatchupPolicy) -> None:
        self.max_frames = policy.max_frames  # 0: no catch-up, gaps reported at once
        self._wait_s = policy.wait_s
        self._holding: set[RobotKey] = set()

    def __len__(self) -> int:
        return len(self._holding)

    def held_back(
        self, session: RobotSession, frame: Frame, now_s: float, out: Outcome, marks: CacheMarks
    ) -> bool:
        """Hold a frame that lies beyond a gap (starting a catch-up); False: apply it now."""
        if session.is_repeat(frame.seq):
            return False  # a duplicate: the table reports it
        if session.hold_until_s is None:
            if frame.seq == session.expected_seq or now_s < session.next_catchup_s:
                return False
            self.start(session, now_s, out)
        if frame.seq in session.held:
            if marks.take(session.key, session.session, frame.seq):
                return True
            session.frames_duplicate += 1
            out.frames_duplicate += 1
            out.reject(
                session.fleet,
                session.robot,
                session.session,
                ErrorCode.DUPLICATE_SEQ,
                f"frame {frame.seq} was already received (held for catch-up)",
                frame.seq,
            )
            return True
        session.held[frame.seq] = frame  # past max_frames, the table releases
        return True

    def start(self, session: RobotSession, now_s: float, out: Outcome) -> None:
        """Hold the session and ask the robot's cache for the frames after the last seen."""
        seen = session.last_seen_seq
        session.hold_until_s = now_s + self._wait_s
        session.next_catchup_s = now_s + self._wait_s
        session.recovered = 0
        self._holding.add(session.key)
        out.catchups.append(
            CatchupRequest(
                session.fleet,
                session.robot,
                session.session,
                -1 if seen is None else seen,
                self.max_frames,
            )
        )

    def contiguous(self, session: RobotSession) -> list[Frame]:
        """Take the held frames that follow the last seq without a gap."""
        expected = session.expected_seq
        run: list[Frame] = []
        while expected in session.held:
            run.append(session.held.pop(expected))
            expected += 1
        return run

    def overflowing(self, session: RobotSession) -> bool:
        """True when more frames are held than a catch-up asks for (invariant 2)."""
        return len(session.held) > self.max_frames

    @staticmethod
    def take_all(session: RobotSession) -> list[Frame]:
        """Take every held frame, in seq order."""
        held = [session.held[seq] for seq in sorted(session.held)]
        session.held.clear()
        return held

    def finish(self, session: RobotSession) -> None:
        """The hold is over (its held end, if any, is the table's to apply)."""
        session.hold_until_s = None
        self._holding.discard(session.key)
        log.info(
            "%s/%s %s: caught up to seq %s, %d frame(s) recovered from the robot's cache",
            session.fleet,
            session.robot,
            session.session,
            session.last_seen_seq,
            session.recovered,
        )

    def take_recovered(
        self, session: RobotSession, frames: Iterable[Frame], out: Outcome, marks: CacheMarks
    ) -> None:
        """Hold frames the robot's cache returned, where the hold still needs them."""
        seen = session.last_seen_seq
        for frame in frames:
            if (
                frame.session != session.session
                or (seen is not None and frame.seq <= seen)
                or frame.seq in session.held
                or len(session.held) >= 2 * self.max_frames
            ):
                continue  # not needed: silently dropped, never an error
            session.held[frame.seq] = frame
            marks.note(session.key, session.session, frame.seq)
            session.recovered += 1
            out.frames_recovered += 1

    def overdue(
        self, now_s: float, open_sessions: Mapping[RobotKey, RobotSession]
    ) -> list[RobotSession]:
        """Sessions whose hold outlived ``wait_s`` (a cache that never answered)."""
        due: list[RobotSession] = []
        for key in list(self._holding):
            session = open_sessions.get(key)
            if session is None:
                self._holding.discard(key)
            elif session.hold_until_s is not None and now_s >= session.hold_until_s:
                due.append(session)
        return due

    def drop(self, session: RobotSession) -> None:
        """Forget a session's hold and what it holds (a hand-over: the new owner asks)."""
        session.held.clear()
        session.held_end = None
        session.hold_until_s = None
        self._holding.discard(session.key)

    def discard(self, key: RobotKey) -> None:
        """Forget a session that left memory by an error."""
        self._holding.discard(key)

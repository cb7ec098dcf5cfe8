"""Frames applied to one session's core: the seq rules, the budgets, coalesced decisions.

Invariants:

1. Frames of a session are applied in ascending seq order exactly once; a repeat never
   reaches the core (``seq.py``), and the second copy of a cached frame is not counted.
2. A refused frame counts as received and rejected, never also missing.
3. A session is decided once every ``decide_every`` applied frames and after the last.
4. A new incarnation (``seq.py``, invariant 6) starts the segmenter afresh: its submaps and
   areas then stand on the frames from the incarnation on, as any replay from there has.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.core import GraphError
from lessmap.runtime.sessions.seq import Repeat
from lessmap_schemas.errors import ErrorCode

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from lessmap.core.segmenter import Segmenter
    from lessmap.runtime.sessions.limits import Budgets
    from lessmap.runtime.sessions.model import Outcome, RobotSession
    from lessmap.runtime.sessions.seq import CacheMarks
    from lessmap_schemas.messages import Frame


class Applier:
    """Applies frames to sessions and decides them, for one table."""

    def __init__(
        self,
        budgets: Budgets,
        marks: CacheMarks,
        clock: Callable[[], float],
        decide_every: int,
        fresh: Callable[[RobotSession], Segmenter],
    ) -> None:
        self._budgets = budgets
        self._marks = marks
        self._fresh = fresh  # a new segmenter for a session (invariant 4)
        self._clock = clock  # only times decisions; activity time is passed in
        self.decide_every = decide_every  # lowered per turn by the table

    def frames(self, session: RobotSession, frames: Iterable[Frame], out: Outcome) -> None:
        """Apply frames (ascending seq) and decide every ``decide_every`` applied."""
        pending = 0
        for frame in frames:
            if self._frame(session, frame, out):
                pending += 1
                session.frames_since_checkpoint += 1
                if pending >= self.decide_every:
                    self.decide(session, out)
                    pending = 0
        if pending:
            self.decide(session, out)

    def _frame(self, session: RobotSession, frame: Frame, out: Outcome) -> bool:
        seq = frame.seq
        if session.is_repeat(seq):
            self._count_repeat(session, seq, out)
            return False
        # From here on the seq counts as received, applied or not: a refused frame is
        # rejected once, never also reported missing.
        incarnation = session.incarnation
        gap = session.advance(seq)
        if gap is not None:
            if session.incarnation != incarnation:  # invariant 4
                session.applied_before += session.segmenter.frames_applied
                session.transitions_before += session.segmenter.transitions
                session.segmenter = self._fresh(session)
                self._budgets.set_edges(session, 0)
            report_gap(session, gap, seq, out)
        refusal = self._budgets.refusal(session, frame)
        if refusal is not None:
            session.frames_rejected += 1
            out.reject(session.fleet, session.robot, session.session, *refusal, seq)
            return False
        try:
            session.segmenter.apply(seq, frame.stamp_s, frame.features)
        except GraphError as exc:
            session.frames_rejected += 1
            out.reject(
                session.fleet, session.robot, session.session, ErrorCode.INVALID, str(exc), seq
            )
            return False
        self._budgets.charge(session, len(frame.features))
        out.frames_applied += 1
        return True

    def _count_repeat(self, session: RobotSession, seq: int, out: Outcome) -> None:
        seen = session.last_seen_seq
        if self._marks.take(session.key, session.session, seq):
            return
        repeat = session.repeat(seq)
        if repeat is Repeat.REDELIVERY:  # from the robot's cache after a restore: no error
            out.frames_duplicate += 1
            return
        if repeat is Repeat.LATE:
            out.frames_late += 1
            code, what = ErrorCode.OUT_OF_ORDER, "arrived after later frames"
        else:
            out.frames_duplicate += 1
            code, what = ErrorCode.DUPLICATE_SEQ, "was already received"
        out.reject(
            session.fleet,
            session.robot,
            session.session,
            code,
            f"frame {seq} {what} (last received {seen})",
            seq,
        )

    def decide(self, session: RobotSession, out: Outcome) -> None:
        """Run the session's spectral test over what was applied since the last one."""
        batch = session.segmenter.pending_frames
        started = self._clock()
        changes = session.segmenter.decide()
        out.decisions.append((self._clock() - started, batch))
        self._budgets.recount(session)
        out.transitions.extend((session, change) for change in changes)


def report_gap(session: RobotSession, gap: tuple[int, int], seq: int | None, out: Outcome) -> None:
    """Count a gap's seqs missing in the outcome and report it (SEQ_GAP)."""
    first, last = gap
    missing = last - first + 1
    out.frames_missing += missing
    out.reject(
        session.fleet,
        session.robot,
        session.session,
        ErrorCode.SEQ_GAP,
        f"{missing} frame(s) missing: {first}..{last}",
        seq,
    )

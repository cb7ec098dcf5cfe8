"""The seq rules of one robot session, pure: no store, no clock, no logging, no messages.

Invariants (the ordering contract, schemas/README.md; ``table.py`` applies them):

1. A seq at or below the last one received is a repeat: a redelivery (at or below the seq
   a session was restored at), a late frame (inside a gap reported earlier) or a duplicate.
2. A seq above the last received counts as received, applied or not; the seqs skipped
   are counted missing once and remembered as a gap range (at most ``GAPS_KEPT``).
3. Exact accounting: a late frame moves its seq from missing to rejected, so no frame is
   counted twice.
4. A frame taken from a robot's cache and also put by the robot counts once: the second of
   the two copies uses up its mark (``CacheMarks``) and is dropped uncounted.
5. A closed session id is never reopened (``ClosedIds``, a few per robot).
6. ``incarnation`` is the first seq of the history held. It changes only when the first
   seq received after a fresh start or a resume (``at_origin``) follows a gap: the frames
   before it were lost here, so what comes next must not reuse the identities published
   from them (schemas/README.md, section 6).
"""

from __future__ import annotations

import enum
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

RobotKey = tuple[str, str]  # (fleet, robot)

GAPS_KEPT = 64  # per session: gap ranges remembered to tell OUT_OF_ORDER from DUPLICATE
CLOSED_IDS_KEPT = 16  # per robot: enough to reject stragglers of recent sessions
CACHE_MARKS_KEPT = 4096  # per robot: frames taken from its cache not yet matched by its put


class Repeat(enum.Enum):
    """What a seq at or below the last received is (invariant 1)."""

    REDELIVERY = "redelivery"  # a cache answering after a restore: a duplicate, no error
    LATE = "late"  # OUT_OF_ORDER: it fills a gap reported earlier
    DUPLICATE = "duplicate"  # DUPLICATE_SEQ


@dataclass(slots=True, kw_only=True)
class SeqState:
    """The seq counters of one session, as its checkpoint keeps them."""

    frames_duplicate: int = 0
    frames_missing: int = 0
    frames_rejected: int = 0
    last_seen_seq: int | None = None  # highest seq received, applied or refused
    gaps: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=GAPS_KEPT))
    restored_seq: int | None = None  # last_seen_seq of the checkpoint it resumed from
    incarnation: int = 0  # invariant 6
    at_origin: bool = True  # nothing received since a fresh start or a resume
    # Frames applied and transitions published in earlier incarnations (their segmenter is
    # gone; the session's counters still count them).
    applied_before: int = 0
    transitions_before: int = 0

    @property
    def expected_seq(self) -> int:
        """The seq that follows the last received without a gap."""
        return 0 if self.last_seen_seq is None else self.last_seen_seq + 1

    def is_repeat(self, seq: int) -> bool:
        """True for a seq at or below the last received."""
        return self.last_seen_seq is not None and seq <= self.last_seen_seq

    def repeat(self, seq: int) -> Repeat:
        """Count a repeated seq (``is_repeat``) and say what it is."""
        if self.restored_seq is not None and seq <= self.restored_seq:
            self.frames_duplicate += 1
            return Repeat.REDELIVERY
        if take_from_gaps(self.gaps, seq):
            self.frames_missing -= 1
            self.frames_rejected += 1
            return Repeat.LATE
        self.frames_duplicate += 1
        return Repeat.DUPLICATE

    def advance(self, seq: int) -> tuple[int, int] | None:
        """Take a seq above the last received; return the gap it reveals, if any.

        A gap right after a fresh start or a resume begins a new incarnation at ``seq``
        (invariant 6); the caller then starts the segmenter afresh (``lost_history``).
        """
        expected = self.expected_seq
        self.last_seen_seq = seq
        at_origin, self.at_origin = self.at_origin, False
        if seq <= expected:
            return None
        if at_origin:
            self.incarnation = seq
        return self.count_gap(expected, seq - 1)

    def count_gap(self, first: int, last: int) -> tuple[int, int]:
        """Count seqs ``first..last`` as missing and remember the range."""
        self.frames_missing += last - first + 1
        self.gaps.append((first, last))
        return (first, last)

    def counters(self) -> dict[str, Any]:
        """The counters, for a checkpoint (JSON-ready)."""
        return {
            "frames_duplicate": self.frames_duplicate,
            "frames_missing": self.frames_missing,
            "frames_rejected": self.frames_rejected,
            "last_seen_seq": self.last_seen_seq,
            "gaps": [list(g) for g in self.gaps],
            "incarnation": self.incarnation,
            "before": [self.applied_before, self.transitions_before],
        }

    def restore_counters(self, meta: dict[str, Any]) -> None:
        """Take back the counters of a checkpoint."""
        self.frames_duplicate = int(meta["frames_duplicate"])
        self.frames_missing = int(meta["frames_missing"])
        self.frames_rejected = int(meta["frames_rejected"])
        seen = meta["last_seen_seq"]
        self.last_seen_seq = self.restored_seq = None if seen is None else int(seen)
        self.gaps.extend((int(lo), int(hi)) for lo, hi in meta["gaps"])
        self.incarnation = int(meta.get("incarnation", 0))
        self.applied_before, self.transitions_before = map(int, meta.get("before", (0, 0)))
        self.at_origin = True  # what the service published after this record may be lost


def take_from_gaps(gaps: deque[tuple[int, int]], seq: int) -> bool:
    """Remove ``seq`` from the reported gap ranges; True when it was in one (a late frame)."""
    for index, (lo, hi) in enumerate(gaps):
        if lo <= seq <= hi:
            del gaps[index]
            # Both halves go back where the range was; a full deque drops its oldest range,
            # and a late frame of a forgotten range then counts as a duplicate.
            for part in ((seq + 1, hi), (lo, seq - 1)):
                if part[0] <= part[1]:
                    gaps.insert(index, part)
            return True
    return False


class CacheMarks:
    """(session, seq) of frames taken from each robot's cache, until the robot's own copy.

    The robot's own put of the same frame, arriving before or after the copy, is the one
    offer of that frame, so the second of the two is dropped uncounted (invariant 4).
    """

    def __init__(self) -> None:
        self._marks: dict[RobotKey, set[tuple[str, int]]] = {}

    def note(self, key: RobotKey, session_id: str, seq: int) -> None:
        """Remember that frame ``seq`` of a session came (or comes) from the robot's cache."""
        marks = self._marks.setdefault(key, set())
        if len(marks) >= CACHE_MARKS_KEPT:
            marks.clear()  # bounded; a forgotten mark only makes a late duplicate counted
        marks.add((session_id, seq))

    def take(self, key: RobotKey, session_id: str, seq: int) -> bool:
        """True (and the mark is used up) when one of two copies of a frame came from a cache."""
        marks = self._marks.get(key)
        if not marks or (session_id, seq) not in marks:
            return False
        marks.discard((session_id, seq))
        if not marks:
            del self._marks[key]
        return True

    def forget(self, leaving: Callable[[str, str], bool]) -> None:
        """Drop the marks of the robots ``leaving`` names."""
        for key in [k for k in self._marks if leaving(*k)]:
            del self._marks[key]


class ClosedIds:
    """The ids of each robot's recently closed sessions (invariant 5), bounded in robots."""

    def __init__(self, max_robots: int) -> None:
        self._max_robots = max_robots
        self._ids: OrderedDict[RobotKey, deque[str]] = OrderedDict()

    def __contains__(self, item: tuple[RobotKey, str]) -> bool:
        key, session_id = item
        return session_id in self._ids.get(key, ())

    def of(self, key: RobotKey) -> list[str]:
        """The robot's closed ids, oldest first."""
        return list(self._ids.get(key, ()))

    def close(self, key: RobotKey, session_id: str) -> None:
        """Remember a session closed here (the robot becomes the most recent)."""
        ids = self._ids.setdefault(key, deque(maxlen=CLOSED_IDS_KEPT))
        ids.append(session_id)
        self._ids.move_to_end(key)
        while len(self._ids) > self._max_robots:
            self._ids.popitem(last=False)

    def remember(self, key: RobotKey, session_ids: Iterable[str]) -> None:
        """Take ids a checkpoint names as closed (kept where the robot stands in the order)."""
        ids = self._ids.setdefault(key, deque(maxlen=CLOSED_IDS_KEPT))
        for session_id in session_ids:
            if session_id not in ids:
                ids.append(session_id)

    def forget(self, leaving: Callable[[str, str], bool]) -> None:
        """Drop the ids of the robots ``leaving`` names."""
        for key in [k for k in self._ids if leaving(*k)]:
            del self._ids[key]

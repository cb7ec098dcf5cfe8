"""Hand-overs without a state file: the records of moved sessions, held in memory a while.

With ``--memory-only`` a hand-over's checkpoints had nowhere to go, so the instance taking
a partition opened every moved session afresh and reported the frames before as a gap.
The store keeps them here instead (``CheckpointStore`` with no file): the old owner answers
the new owner's checkpoint query from it, the new owner keeps what it fetched here until
the robot's next frame resumes the session. A record stays ``keep_s`` at most: a robot that
never comes back must not hold memory, and after that long its session would have moved on.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.runtime.record import RobotKey, SessionRecord

KEEP_S = 120.0  # far above a hand-over's release wait and fetch (seconds each)
_PRUNE_EVERY_S = 1.0  # a resume burst after a big hand-over must not scan the shelf per frame


class MemoryShelf:
    """The newest record of each robot, for ``keep_s`` (pruned once a second); thread-safe."""

    def __init__(self, keep_s: float = KEEP_S, clock: Callable[[], float] = time.monotonic) -> None:
        self._keep_s = keep_s
        self._clock = clock
        self._lock = threading.Lock()
        self._records: dict[RobotKey, tuple[SessionRecord, float]] = {}
        self._next_prune = float("-inf")

    def __len__(self) -> int:
        with self._lock:
            self._prune()
            return len(self._records)

    def put(self, record: SessionRecord) -> None:
        """Keep this instance's own record of a robot (it replaces the robot's last)."""
        with self._lock:
            self._prune()
            self._records[record.key] = (record, self._clock())

    def offer(self, record: SessionRecord) -> bool:
        """Keep another instance's record if it is newer than the one held; True if kept."""
        with self._lock:
            self._prune()
            held = self._records.get(record.key)
            if not record.newer_than(None if held is None else held[0]):
                return False
            self._records[record.key] = (record, self._clock())
            return True

    def get(self, key: RobotKey) -> SessionRecord | None:
        """The robot's record, if one is held."""
        with self._lock:
            self._prune()
            held = self._records.get(key)
            return None if held is None else held[0]

    def drop(self, key: RobotKey) -> None:
        """Forget the robot's record (resumed, or unreadable)."""
        with self._lock:
            self._records.pop(key, None)

    def drop_where(self, gone: Callable[[str, str], bool]) -> None:
        """Forget the records of every robot ``gone`` names."""
        with self._lock:
            for key in [k for k in self._records if gone(*k)]:
                del self._records[key]

    def where(self, keep: Callable[[str, str], bool]) -> list[SessionRecord]:
        """Every held record whose robot ``keep`` names."""
        with self._lock:
            self._prune()
            return [record for key, (record, _) in self._records.items() if keep(*key)]

    def _prune(self) -> None:
        now = self._clock()
        if now < self._next_prune:
            return
        self._next_prune = now + _PRUNE_EVERY_S
        oldest = now - self._keep_s
        for key in [k for k, (_, at) in self._records.items() if at < oldest]:
            del self._records[key]

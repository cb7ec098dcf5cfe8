"""A running fleet's trajectories for its room map: poses and transitions per robot session.

Sans-IO: ``follow`` hands it the frames and transitions it receives; ``tracks`` returns each
labelled trajectory, ready for ``roommap.fleet_room_map``. A track is one robot session and
one incarnation of it: after lost state the service numbers areas afresh from a new
incarnation, so its areas are not the earlier ones (rule 4 merges them where they overlap).

Bounded: a session keeps at most ``max_poses_per_session`` poses. When full it keeps every
other one and from then on every second frame (then fourth, ...), so the whole walk stays
covered at a coarser step instead of its start being forgotten. A transition is kept once
(its identity: session, incarnation, closed submap), so a resent history adds nothing.
"""

from __future__ import annotations

from array import array
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from lessmap.floorplan.metric import Cut
from lessmap.floorplan.streams import frame_areas

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from lessmap_schemas.messages import Frame, Transition

__all__ = ["LiveTrack", "LiveTrajectories"]

#: About 5.5 hours of a robot at 10 frames a second (24 bytes a pose: 4.8 MB a session).
MAX_POSES_PER_SESSION = 200_000
#: Robot sessions followed at once; the one that sent nothing for longest goes first.
MAX_SESSIONS = 2_000


@dataclass(slots=True)
class _Session:
    seqs: array[int] = field(default_factory=lambda: array("q"))
    xs: array[float] = field(default_factory=lambda: array("d"))
    ys: array[float] = field(default_factory=lambda: array("d"))
    stride: int = 1  # keep one frame in `stride` once thinned
    since_kept: int = 0
    last_seq: int = -1
    # (incarnation, closed submap id) -> the transition's cut
    cuts: dict[tuple[int, int], Cut] = field(default_factory=dict)
    touched: int = 0  # the follower's message count at its last frame or transition


@dataclass(frozen=True, slots=True)
class LiveTrack:
    """One labelled trajectory: poses (m) in seq order and each pose's area."""

    robot: str
    name: str  # robot/session, with #incarnation after lost state
    seqs: NDArray[np.int64]
    xy: NDArray[np.float64]
    areas: NDArray[np.int64]


class LiveTrajectories:
    """Per robot session, its poses and its transitions as they arrive."""

    def __init__(
        self,
        max_poses_per_session: int = MAX_POSES_PER_SESSION,
        max_sessions: int = MAX_SESSIONS,
    ) -> None:
        if max_poses_per_session < 2 or max_sessions < 1:
            msg = "max_poses_per_session must be >= 2 and max_sessions >= 1"
            raise ValueError(msg)
        self.max_poses = max_poses_per_session
        self.max_sessions = max_sessions
        self.counts: Counter[str] = Counter()
        self._sessions: dict[tuple[str, str], _Session] = {}
        self._clock = 0
        self.changed = False  # set by anything that can change a room map; the caller clears

    def add_frame(self, robot: str, frame: Frame) -> None:
        """Note the frame's pose (frames without one are counted, not kept)."""
        self.counts["frames"] += 1
        if frame.pose is None:
            self.counts["frames without a pose"] += 1
            return
        entry = self._entry(robot, frame.session)
        if frame.seq <= entry.last_seq:
            self.counts["frames repeated or out of order"] += 1
            return
        entry.last_seq = frame.seq
        entry.since_kept += 1
        if entry.since_kept < entry.stride:
            return
        entry.since_kept = 0
        entry.seqs.append(frame.seq)
        entry.xs.append(frame.pose[0])
        entry.ys.append(frame.pose[1])
        if len(entry.seqs) >= self.max_poses:
            # Every other pose: the whole walk at half the detail, within the same memory.
            entry.seqs, entry.xs, entry.ys = entry.seqs[::2], entry.xs[::2], entry.ys[::2]
            entry.stride *= 2
            self.counts["sessions thinned"] += 1
        self.changed = True

    def add_transition(self, transition: Transition) -> None:
        """Note the transition (once, whatever the number of copies received)."""
        self.counts["transitions"] += 1
        entry = self._entry(transition.robot, transition.session)
        identity = (transition.incarnation, transition.closed.id)
        if identity in entry.cuts:
            self.counts["transitions repeated"] += 1
            return
        entry.cuts[identity] = Cut(
            transition.seq, transition.boundary_seq, transition.area, transition.revisit
        )
        self.changed = True

    def tracks(self) -> list[LiveTrack]:
        """Every session's labelled trajectory with poses, by robot and session name."""
        out = []
        for (robot, session), entry in sorted(self._sessions.items()):
            if not entry.seqs:
                continue
            seqs = np.frombuffer(entry.seqs, dtype=np.int64).copy()
            xy = np.column_stack(
                (np.frombuffer(entry.xs, dtype=np.float64), np.frombuffer(entry.ys, np.float64))
            )
            incarnations = sorted({0, *(i for i, _ in entry.cuts)})
            # A pose belongs to the latest incarnation that starts at or before it.
            which = np.searchsorted(np.asarray(incarnations), seqs, side="right") - 1
            for index, incarnation in enumerate(incarnations):
                mine = which == index
                if not mine.any():
                    continue
                cuts = [c for (i, _), c in entry.cuts.items() if i == incarnation]
                name = f"{robot}/{session}" + (f"#{incarnation}" if incarnation else "")
                areas = frame_areas(seqs[mine], cuts)
                out.append(LiveTrack(robot, name, seqs[mine], xy[mine], areas))
        return out

    @property
    def poses(self) -> int:
        """Poses held over all sessions."""
        return sum(len(entry.seqs) for entry in self._sessions.values())

    def _entry(self, robot: str, session: str) -> _Session:
        self._clock += 1
        key = (robot, session)
        entry = self._sessions.get(key)
        if entry is None:
            if len(self._sessions) >= self.max_sessions:
                stalest = min(self._sessions, key=lambda k: self._sessions[k].touched)
                del self._sessions[stalest]
                self.counts["sessions dropped (too many)"] += 1
            entry = self._sessions[key] = _Session()
        entry.touched = self._clock
        return entry

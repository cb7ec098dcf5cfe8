"""What the viewer knows of a fleet: per robot, its poses by seq, submaps and transitions.

Built only from what is on the bus: the robots' frames (seq, stamp, pose, features) and the
service's transitions. A frame's submap is the number of transitions of its session whose
``boundary_seq`` is at or before the frame's seq, so a trajectory is coloured exactly where
the service put each boundary. No I/O, no clock: the feed calls it from one thread.

A track is one robot *session*, not one robot name: a robot that starts a new session (a
restart, a second run under the same name, a session the service closed) gets a new track,
with submaps numbered from 0 again. The track it leaves is kept as ``previous`` (one per
robot, so restarts do not pile up), for the scene to draw dimmed; frames that still arrive
for it are dropped.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from itertools import combinations
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap_schemas.messages import Frame, Transition

#: Poses kept per robot (about half an hour at 10 Hz): a trajectory is bounded in memory.
MAX_POINTS = 20000
#: Frames of the current submap kept per robot for its CovGraph.
MAX_GRAPH_FRAMES = 2000


@dataclass(frozen=True, slots=True)
class Point:
    """A pose of the robot at one frame."""

    seq: int
    stamp_s: float
    x: float
    y: float
    theta: float


@dataclass(frozen=True, slots=True)
class Mark:
    """A transition, where it happened (the pose at its boundary, if the robot has poses)."""

    seq: int
    boundary_seq: int
    stamp_s: float
    closed: int
    opened: int
    reason: str
    ncut: float | None
    lambda2: float | None
    at: Point | None
    order: int  # arrival order among the fleet's marks (robots' clocks are not comparable)
    left_area: int = 0
    area: int = 0
    revisit: bool = False
    batch_frames: int = 1


@dataclass
class Track:
    """One robot session as the viewer saw it."""

    robot: str
    session: str
    points: deque[Point] = field(default_factory=lambda: deque(maxlen=MAX_POINTS))
    marks: list[Mark] = field(default_factory=list)
    frames: deque[tuple[int, tuple[int, ...], tuple[float, float] | None]] = field(
        default_factory=lambda: deque(maxlen=MAX_GRAPH_FRAMES)
    )
    last_seq: int = -1

    def submap_of(self, seq: int) -> int:
        """Return the submap id of frame ``seq`` (transitions seen so far)."""
        return sum(1 for mark in self.marks if mark.boundary_seq <= seq)

    def pose_at(self, seq: int) -> Point | None:
        """Return the pose of the last frame at or before ``seq``, if any."""
        found = None
        for point in self.points:
            if point.seq > seq:
                break
            found = point
        return found


@dataclass(frozen=True, slots=True)
class CovGraph:
    """The covisibility graph of a robot's current submap, as its frames show it.

    ``nodes`` maps a feature to (n_i, where it was seen: the mean pose of the frames that saw
    it, or None without poses); ``edges`` maps a pair to (a_ij, CovRate W_ij = a_ij / min(n_i,
    n_j)), the paper's Eq. 1.
    """

    nodes: dict[int, tuple[int, tuple[float, float] | None]]
    edges: dict[tuple[int, int], tuple[int, float]]


class FleetModel:
    """Every robot of one fleet; fed frames and transitions, read by the scene builder."""

    def __init__(self, fleet: str) -> None:
        self.fleet = fleet
        self.tracks: dict[str, Track] = {}
        #: Per robot, the session it had before its current one (if that one had poses).
        self.previous: dict[str, Track] = {}
        #: Changes whenever the fleet's set of marks changes (a mark, a track replaced).
        self.marks_version = 0
        self._marks_seen = 0

    def on_frame(self, robot: str, frame: Frame) -> Track | None:
        """Add a frame; a new session starts a new track.

        Returns:
            The robot's track, or None if the frame was not applied: a repeat (a cache's
            redelivery) or a late frame of the session the robot left.
        """
        track = self.tracks.get(robot)
        if track is None or track.session != frame.session:
            left = self.previous.get(robot)
            if left is not None and left.session == frame.session:
                return None
            track = self._new_track(robot, frame.session)
        if frame.seq <= track.last_seq:
            return None
        track.last_seq = frame.seq
        where = None
        if frame.pose is not None:
            x, y, theta = frame.pose
            track.points.append(Point(frame.seq, frame.stamp_s, x, y, theta))
            where = (x, y)
        track.frames.append((frame.seq, tuple(frame.features), where))
        return track

    def on_transition(self, t: Transition) -> Mark | None:
        """Add a transition; return its mark (None for a repeat or another session's)."""
        track = self.tracks.get(t.robot)
        if track is not None and track.session != t.session and track.last_seq >= 0:
            return None  # an older session's (history): the robot's frames are of another
        left = self.previous.get(t.robot)
        if left is not None and left.session == t.session:
            return None  # the session the robot left: its track is drawn without marks
        if track is None or track.session != t.session:
            track = self._new_track(t.robot, t.session)
        if any(mark.opened == t.opened.id for mark in track.marks):
            return None
        self._marks_seen += 1
        mark = Mark(
            seq=t.seq,
            boundary_seq=t.boundary_seq,
            stamp_s=t.stamp_s,
            closed=t.closed.id,
            opened=t.opened.id,
            reason=t.reason,
            ncut=t.ncut,
            lambda2=t.lambda2,
            at=track.pose_at(t.boundary_seq),
            order=self._marks_seen,
            left_area=t.left_area,
            area=t.area,
            revisit=t.revisit,
            batch_frames=t.batch_frames,
        )
        track.marks.append(mark)
        track.marks.sort(key=lambda m: m.boundary_seq)
        self.marks_version += 1
        return mark

    def _new_track(self, robot: str, session: str) -> Track:
        old = self.tracks.get(robot)
        if old is not None:
            if old.points:
                self.previous[robot] = old
            if old.marks:
                self.marks_version += 1
        track = self.tracks[robot] = Track(robot, session)
        return track

    def covgraph(self, robot: str, max_nodes: int = 400) -> CovGraph | None:
        """Return the CovGraph of the robot's current submap (its most seen features)."""
        track = self.tracks.get(robot)
        if track is None:
            return None
        start = max((mark.boundary_seq for mark in track.marks), default=0)
        frames = [(features, where) for seq, features, where in track.frames if seq >= start]
        return covgraph_of(frames, max_nodes)


def covgraph_of(
    frames: Sequence[tuple[tuple[int, ...], tuple[float, float] | None]], max_nodes: int
) -> CovGraph:
    """Count n_i and a_ij over ``frames``; keep the ``max_nodes`` most seen features."""
    seen: Counter[int] = Counter()
    for features, _ in frames:
        seen.update(set(features))
    keep = {feature for feature, _ in seen.most_common(max_nodes)}
    sums: dict[int, list[float]] = {}
    pairs: Counter[tuple[int, int]] = Counter()
    for features, where in frames:
        kept = sorted(set(features) & keep)
        pairs.update(combinations(kept, 2))
        if where is not None:
            for feature in kept:
                total = sums.setdefault(feature, [0.0, 0.0, 0.0])
                total[0] += where[0]
                total[1] += where[1]
                total[2] += 1
    nodes = {
        f: (seen[f], (sums[f][0] / sums[f][2], sums[f][1] / sums[f][2]) if f in sums else None)
        for f in sorted(keep)
    }
    edges = {(i, j): (a, a / min(seen[i], seen[j])) for (i, j), a in sorted(pairs.items())}
    return CovGraph(nodes, edges)

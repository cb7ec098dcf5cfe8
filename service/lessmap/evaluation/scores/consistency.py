"""Consistency of transitions with a simulated building's ground truth (paper Figs. 5, 8, 11).

The detections of each method over a run's frames and the door spreads. Recall, precision,
latency and their variants are ``lessmap.sim.groundtruth``'s (the demo's scorer too), with
``tolerance_frames`` and ``door_distance_m`` passed explicitly. On top of them, the revisit
spread: each true change is matched to its first detection before the robot's next room
change; for every door crossed several times, the true positions at the matches are
compared pairwise, grouped by door and by passage (door and direction). A small spread
means revisits give matching partitions (in full: ``docs/design/evaluation.md``).
"""

from __future__ import annotations

import itertools
import math
import statistics
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

from lessmap.core import Partitioner
from lessmap.core.areas.tracker import AreaTracker
from lessmap.evaluation.baselines import fixed_features
from lessmap.sim import groundtruth

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from lessmap.core import PartitionParams
    from lessmap.core.areas.tracker import AreaParams
    from lessmap.files.frames import FrameRow
    from lessmap.sim.simulator import RoomChange, SimTruth

DEFAULT_TOLERANCE_FRAMES = 8  # 4 s at the simulator's 2 Hz: the CovRate needs a few frames
# (lessmap.sim.groundtruth.score defaults to 5: the evaluation always passes its own)
DEFAULT_DOOR_DISTANCE_M = 2.0


@dataclass(frozen=True, slots=True)
class Detection:
    """A transition of one robot: detection frame, estimated first frame, reason."""

    robot: str
    seq: int
    boundary_seq: int
    reason: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class Spread:
    """Transition points of repeated crossings of one door (or one passage), metres."""

    door: int
    to_room: int | None  # None: both directions together
    crossings: int  # true crossings
    matched: int  # crossings with a detection before the next room change
    boundary_mean_m: float | None  # mean pairwise distance at boundary_seq (None: < 2 matched)
    boundary_max_m: float | None
    seq_mean_m: float | None  # the same at the detection frame
    seq_max_m: float | None
    boundary_to_door_m: float | None  # mean distance of the boundary points to the door


@dataclass(frozen=True, slots=True, kw_only=True)
class Consistency:
    """How one segmentation method matches the true room changes of a simulated run."""

    method: str
    changes: int
    transitions: int
    tolerance_frames: int
    door_distance_m: float
    recall: float | None  # None: nothing to find
    recall_boundary: float | None
    recall_any: float | None
    precision: float | None  # None: nothing detected
    precision_boundary: float | None
    precision_door: float | None
    latency_mean: float | None  # frames
    latency_median: float | None
    latency_max: int | None
    doors: tuple[Spread, ...]  # per door, both directions
    passages: tuple[Spread, ...]  # per door and direction

    def spread(self, *, passages: bool = False, at: str = "boundary") -> tuple[float, float] | None:
        """Return (mean over doors of the mean spread, max over doors of the max), metres.

        Args:
            passages: group by door and direction instead of by door.
            at: ``"boundary"`` (positions at boundary_seq) or ``"seq"`` (detection frame).
        """
        groups = self.passages if passages else self.doors
        pairs = [
            (getattr(g, f"{at}_mean_m"), getattr(g, f"{at}_max_m"))
            for g in groups
            if getattr(g, f"{at}_mean_m") is not None
        ]
        if not pairs:
            return None
        return statistics.fmean(p[0] for p in pairs), max(p[1] for p in pairs)

    def as_dict(self) -> dict[str, Any]:
        """Return the figures as JSON-ready values."""
        return asdict(self)


def lessmap_detections(frames: Iterable[FrameRow], params: PartitionParams) -> list[Detection]:
    """Run one partitioner per robot over the frames (file order); return the transitions."""
    partitioners: dict[str, Partitioner] = {}
    found: list[Detection] = []
    for frame in frames:
        partitioner = partitioners.get(frame.robot)
        if partitioner is None:
            partitioner = partitioners[frame.robot] = Partitioner(params)
        transition = partitioner.observe(frame.seq, frame.stamp_s, frame.features)
        if transition is not None:
            found.append(
                Detection(
                    frame.robot, transition.seq, transition.boundary_seq, str(transition.reason)
                )
            )
    return found


def area_detections(frames: Iterable[FrameRow], params: AreaParams) -> list[Detection]:
    """Run one area tracker per robot over the frames (file order); return its changes."""
    trackers: dict[str, AreaTracker] = {}
    found: list[Detection] = []
    for frame in frames:
        tracker = trackers.get(frame.robot)
        if tracker is None:
            tracker = trackers[frame.robot] = AreaTracker(params)
        change = tracker.observe(frame.seq, frame.stamp_s, frame.features)
        if change is not None:
            t = change.transition
            found.append(Detection(frame.robot, t.seq, t.boundary_seq, str(change.reason)))
    return found


def fixed_feature_detections(frames: Sequence[FrameRow], limit: int) -> list[Detection]:
    """Boundaries of the fixed-features baseline per robot: the first frame of each submap."""
    found: list[Detection] = []
    for robot in sorted({frame.robot for frame in frames}):
        mine = [frame for frame in frames if frame.robot == robot]
        labels = fixed_features([frame.features for frame in mine], limit)
        for before, frame, label in zip(labels, mine[1:], labels[1:], strict=False):
            if label != before:
                found.append(Detection(robot, frame.seq, frame.seq, "FIXED"))
    return found


def _pairwise(points: Sequence[tuple[float, float]]) -> list[float]:
    return [math.dist(a, b) for a, b in itertools.combinations(points, 2)]


def _spread(
    door: int, to_room: int | None, crossings: int, matched: list[tuple[Any, Any, Any]]
) -> Spread:
    """Spread of matched crossings: (boundary point, detection point, door point) each."""
    at_boundary = _pairwise([m[0] for m in matched])
    at_seq = _pairwise([m[1] for m in matched])
    return Spread(
        door=door,
        to_room=to_room,
        crossings=crossings,
        matched=len(matched),
        boundary_mean_m=statistics.fmean(at_boundary) if at_boundary else None,
        boundary_max_m=max(at_boundary, default=None),
        seq_mean_m=statistics.fmean(at_seq) if at_seq else None,
        seq_max_m=max(at_seq, default=None),
        boundary_to_door_m=statistics.fmean(math.dist(m[0], m[2]) for m in matched)
        if matched
        else None,
    )


def score(
    truth: SimTruth,
    detections: Sequence[Detection],
    *,
    method: str = "",
    tolerance_frames: int = DEFAULT_TOLERANCE_FRAMES,
    door_distance_m: float = DEFAULT_DOOR_DISTANCE_M,
) -> Consistency:
    """Score detections against the true room changes (figures: module docstring).

    Raises:
        ValueError: a negative tolerance or distance, or a detection or change at a frame
            the truth has no position for (spread and door figures need positions).
    """
    where = truth.positions()
    doors = {door.id: (door.x, door.y) for door in truth.doors}

    def position(robot: str, seq: int) -> tuple[float, float]:
        try:
            return where[(robot, seq)]
        except KeyError:
            msg = f"no true position of robot {robot!r} at seq {seq}"
            raise ValueError(msg) from None

    found: dict[str, list[Detection]] = {}
    for detection in detections:
        found.setdefault(detection.robot, []).append(detection)
    figures = groundtruth.score(
        truth.changes,
        found,
        positions=where,
        doors=list(doors.values()) or None,  # no doors: no door figure (None, not 0)
        tolerance_frames=tolerance_frames,
        distance_m=door_distance_m,
    )
    if doors:
        for detection in detections:  # every door figure needs its position
            position(detection.robot, detection.boundary_seq)
    changes: dict[str, list[RoomChange]] = {}
    for change in truth.changes:
        changes.setdefault(change.robot, []).append(change)
    groups: dict[tuple[int, int | None], list[tuple[Any, Any, Any]]] = {}
    crossings: dict[tuple[int, int | None], int] = {}
    for robot, mine in changes.items():
        mine.sort(key=lambda c: c.seq)
        dets = sorted(found.get(robot, []), key=lambda d: d.seq)
        for change, after in zip(mine, [*(c.seq for c in mine[1:]), math.inf], strict=True):
            if change.door not in doors:
                continue
            first = next((d for d in dets if change.seq <= d.seq < after), None)
            for key in ((change.door, None), (change.door, change.to_room)):
                crossings[key] = crossings.get(key, 0) + 1
                if first is not None:
                    point = (position(robot, first.boundary_seq), position(robot, first.seq))
                    groups.setdefault(key, []).append((*point, doors[change.door]))
    keys = sorted(crossings, key=lambda k: (k[0], -1 if k[1] is None else k[1]))
    spreads = [_spread(*key, crossings[key], groups.get(key, [])) for key in keys]
    median = figures.latency_median
    return Consistency(
        method=method,
        changes=figures.changes,
        transitions=figures.transitions,
        tolerance_frames=figures.tolerance_frames,
        door_distance_m=figures.distance_m,
        recall=figures.recall,
        recall_boundary=figures.recall_boundary,
        recall_any=figures.recall_any,
        precision=figures.precision,
        precision_boundary=figures.precision_boundary,
        precision_door=figures.precision_door,
        latency_mean=figures.latency_mean,
        latency_median=None if median is None else float(median),
        latency_max=figures.latency_max,
        doors=tuple(s for s in spreads if s.to_room is None),
        passages=tuple(s for s in spreads if s.to_room is not None),
    )

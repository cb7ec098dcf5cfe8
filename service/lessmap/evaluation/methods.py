"""Run either segmentation method over frames, and score revisits against a simulated truth.

``paper`` is one ``Partitioner`` per robot (every transition opens a new submap); ``areas``
one ``AreaTracker``. Both give, per robot, a list of ``AreaEvent``: the detection frame, the
first frame in the new area, the area entered and the size of the segment closed.

Revisit scoring (``revisit_score``): a *visit* is a maximal run of a robot's frames in one
true room, its area the one most of its frames carry; *recognised* counts returns to a room
given the area of its first visit, *false* visits given an area first given to another room
(in full: ``docs/design/evaluation.md``).
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lessmap.core import Partitioner, PartitionParams
from lessmap.core.areas.tracker import AreaParams, AreaTracker
from lessmap.core.rooms.params import RoomParams
from lessmap.core.rooms.tracker import RoomTracker

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence
    from pathlib import Path

    from lessmap.files.frames import FrameRow
    from lessmap.sim.simulator import TruthRow

METHODS = ("paper", "areas", "rooms")

#: The shared data sets whose frames leave out the empty ones: MRCLAM's frames are a robot's
#: sightings that share a stamp (its ``meta.json``), so a robot that sees nothing sends
#: nothing and its blindness is a gap between stamps. Declared, as a user declares a source
#: (``segment --empty-frames-omitted``, ``serve --empty-frames-omitted FLEET``).
EMPTY_FRAMES_OMITTED = frozenset({"mrclam6", "mrclam1_w1s"})


def add_spans_in_views_option(parser: argparse.ArgumentParser) -> None:
    """``--[no-]spans-in-views``: ``AreaParams.spans_in_views`` for the offline studies."""
    parser.add_argument(
        "--spans-in-views",
        action=argparse.BooleanOptionalAction,
        default=AreaParams().spans_in_views,
        help="areas: its confirmation spans grow with the stream's view changes (default "
        "on; --no-spans-in-views: in frames)",
    )


def dataset_area_params(path: Path, base: AreaParams | None = None) -> AreaParams:
    """``base`` (the defaults) for a shared data set's frames file (``EMPTY_FRAMES_OMITTED``)."""
    name = path.name.removesuffix(".frames.jsonl")
    base = base if base is not None else AreaParams()
    return base.for_stream(empty_frames_omitted=name in EMPTY_FRAMES_OMITTED)


@dataclass(frozen=True, slots=True)
class AreaEvent:
    """One transition of one robot, whatever method found it."""

    robot: str
    seq: int  # detection frame
    boundary_seq: int  # estimated first frame in the area entered
    stamp_s: float
    area: int  # area entered (paper: the new submap's id)
    left_area: int
    revisit: bool  # the method named an area it had seen before
    closed_features: int  # distinct features of the segment closed
    reason: str  # SPECTRAL or DISCONNECTED; RECOGNISED for an area recognised (areas' rule 5)


@dataclass(frozen=True, slots=True, kw_only=True)
class RevisitScore:
    """How well a segmentation names the rooms a robot returns to."""

    visits: int
    revisits: int  # visits to a room seen before
    recognised: int  # of those, given the area of the room's first visit
    false: int  # visits given an area first given to another room

    @property
    def recognised_share(self) -> float | None:
        """Recognised revisits over revisits (None without revisits)."""
        return self.recognised / self.revisits if self.revisits else None

    @property
    def false_share(self) -> float | None:
        """False area names over visits (None without visits)."""
        return self.false / self.visits if self.visits else None

    def __add__(self, other: RevisitScore) -> RevisitScore:
        """Pool two scores (several runs)."""
        return RevisitScore(
            visits=self.visits + other.visits,
            revisits=self.revisits + other.revisits,
            recognised=self.recognised + other.recognised,
            false=self.false + other.false,
        )


def run_method(
    frames: Iterable[FrameRow],
    method: str,
    *,
    paper: PartitionParams | None = None,
    areas: AreaParams | None = None,
    rooms: RoomParams | None = None,
) -> dict[str, list[AreaEvent]]:
    """Run one segmenter per robot over the frames (file order), deciding at every frame.

    Args:
        frames: the frames of one or several robots.
        method: ``paper``, ``areas`` or ``rooms``.
        paper: the paper partitioner's parameters (default: the laser profile).
        areas: the area tracker's parameters (default: ``AreaParams()``).
        rooms: the room tracker's parameters (default: ``RoomParams()``).

    Returns:
        Per robot (in order of first frame), its events in order.
    """
    if method not in METHODS:
        msg = f"unknown method {method!r}; choose one of {', '.join(METHODS)}"
        raise ValueError(msg)
    found: dict[str, list[AreaEvent]] = {}
    partitioners: dict[str, Partitioner] = {}
    trackers: dict[str, AreaTracker | RoomTracker] = {}
    for frame in frames:
        mine = found.setdefault(frame.robot, [])
        if method == "paper":
            partitioner = partitioners.get(frame.robot)
            if partitioner is None:
                partitioner = partitioners[frame.robot] = Partitioner(paper)
            transition = partitioner.observe(frame.seq, frame.stamp_s, frame.features)
            if transition is not None:
                mine.append(
                    AreaEvent(
                        robot=frame.robot,
                        seq=transition.seq,
                        boundary_seq=transition.boundary_seq,
                        stamp_s=transition.stamp_s,
                        area=transition.opened.id,
                        left_area=transition.closed.id,
                        revisit=False,
                        closed_features=len(transition.closed.features),
                        reason=str(transition.reason),
                    )
                )
            continue
        tracker = trackers.get(frame.robot)
        if tracker is None:
            tracker = trackers[frame.robot] = (
                RoomTracker(rooms) if method == "rooms" else AreaTracker(areas)
            )
        change = tracker.observe(frame.seq, frame.stamp_s, frame.features)
        if change is not None:
            t = change.transition
            mine.append(
                AreaEvent(
                    robot=frame.robot,
                    seq=t.seq,
                    boundary_seq=t.boundary_seq,
                    stamp_s=t.stamp_s,
                    area=change.area,
                    left_area=change.left_area,
                    revisit=change.revisit_of is not None,
                    closed_features=len(t.closed.features),
                    reason=str(change.reason),
                )
            )
    return found


def area_of_frames(seqs: Sequence[int], events: Sequence[AreaEvent]) -> list[int]:
    """Label each frame (seq order) with the area of the last event at or before it."""
    starts = sorted((event.boundary_seq, index) for index, event in enumerate(events))
    labels: list[int] = []
    current, position = 0, 0
    for seq in seqs:
        while position < len(starts) and starts[position][0] <= seq:
            current = events[starts[position][1]].area
            position += 1
        labels.append(current)
    return labels


def revisit_score(
    truth_rows: Iterable[TruthRow], events: dict[str, list[AreaEvent]]
) -> RevisitScore:
    """Score area names against the true rooms (rules in the module docstring).

    Args:
        truth_rows: rows with ``robot``, ``seq`` and ``room`` (e.g. ``SimRun.truth``).
        events: per robot, its events (``run_method``).
    """
    rooms: dict[str, list[tuple[int, int]]] = {}
    for row in truth_rows:
        rooms.setdefault(row.robot, []).append((row.seq, row.room))
    total = RevisitScore(visits=0, revisits=0, recognised=0, false=0)
    for robot, rows in rooms.items():
        rows.sort()
        labels = area_of_frames([seq for seq, _ in rows], events.get(robot, []))
        visits: list[tuple[int, Counter[int]]] = []
        for (_, room), label in zip(rows, labels, strict=True):
            if not visits or visits[-1][0] != room:
                visits.append((room, Counter()))
            visits[-1][1][label] += 1
        first_area: dict[int, int] = {}  # room -> area of its first visit
        owner: dict[int, int] = {}  # area -> room it was first given to
        revisits = recognised = false = 0
        for room, counts in visits:
            area = counts.most_common(1)[0][0]
            if room in first_area:
                revisits += 1
                recognised += area == first_area[room]
            if owner.setdefault(area, room) != room:
                false += 1
            first_area.setdefault(room, area)
        total += RevisitScore(
            visits=len(visits), revisits=revisits, recognised=recognised, false=false
        )
    return total

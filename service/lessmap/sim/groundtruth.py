"""Score detected transitions against true room changes (simulation or surveyed ground truth).

The one scorer of the project: the demo and the evaluation
(``lessmap.evaluation.scores.consistency``, which adds the door spreads) both call ``score``,
each passing its window and distance.

Pure Python, no I/O: feed it what you have in memory, whether ``RoomChange`` objects from the
simulator, rows read back from a ``<name>.truth.jsonl``, core ``Transition`` objects, wire
``Transition`` messages or the offline output's dicts. Records are read by field name,
as attributes or mapping keys.

Figures, with ``tol`` = ``tolerance_frames``:

- recall: share of true changes (seq ``c``) followed by a detection with
  ``c <= seq <= c + tol``. The spectral test needs a few frames in the new room before the
  split shows, so the window opens at the change and runs forward only.
- recall_boundary: the same with the detection's ``boundary_seq`` (its estimate of the first
  frame in the new area) within ``c ± tol``.
- precision: share of detections whose ``seq`` lies within ``± tol`` of a true change of
  the same robot; precision_boundary likewise with ``boundary_seq``.
- precision_door: share of detections whose robot stood within ``distance_m`` of a door at
  the detection's ``boundary_seq``; precision_door_at_seq uses the detection frame itself.
  None without ``positions`` or ``doors``, or when a detection's position is unknown; an
  empty ``doors`` gives 0 (pass None for "not applicable" in a building without doors).
- recall_any: share of true changes followed by a detection at all before the robot's next
  room change (late counts, missed does not).
- latency: ``seq - c`` for the first detection in ``[c, next change)``, frames, over the
  changes that have one (so it is not cut off at ``tol``).
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["Score", "changes_from_truth", "positions_from_truth", "score"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Score:
    """How well detected transitions match the true room changes."""

    changes: int  # true room changes
    transitions: int  # detections
    tolerance_frames: int
    distance_m: float
    recall: float | None  # None when there is nothing to find
    recall_boundary: float | None
    recall_any: float | None
    precision: float | None  # None when nothing was detected
    precision_boundary: float | None
    precision_door: float | None  # None without positions and doors
    precision_door_at_seq: float | None
    latency_mean: float | None  # frames, over the changes found before the next one
    latency_median: float | None
    latency_max: int | None

    def as_dict(self) -> dict[str, Any]:
        """Return the figures as JSON-ready values (ratios rounded to 4 places)."""
        return {k: round(v, 4) if isinstance(v, float) else v for k, v in asdict(self).items()}

    def describe(self) -> str:
        """One line for a summary: recall, precision, door precision and latency."""

        def pct(value: float | None) -> str:
            return "n/a" if value is None else f"{100 * value:.0f}%"

        latency = "n/a" if self.latency_mean is None else f"{self.latency_mean:.1f}"
        return (
            f"{self.changes} room changes, {self.transitions} transitions: "
            f"recall {pct(self.recall)} (boundary {pct(self.recall_boundary)}, "
            f"any delay {pct(self.recall_any)}), "
            f"precision {pct(self.precision)} (boundary {pct(self.precision_boundary)}), "
            f"near a door {pct(self.precision_door)}, "
            f"latency {latency} frames (median {self.latency_median}, max {self.latency_max}); "
            f"windows ±{self.tolerance_frames} frames, {self.distance_m} m"
        )


def score(
    changes: Iterable[Any],
    detections: Mapping[str, Iterable[Any]],
    *,
    positions: Mapping[tuple[str, int], tuple[float, float]] | None = None,
    doors: Iterable[tuple[float, float]] | None = None,
    tolerance_frames: int = 5,
    distance_m: float = 2.0,
) -> Score:
    """Score detections against true room changes.

    Args:
        changes: True room changes, each with ``robot`` and ``seq`` (first frame in the
            new room), e.g. ``SimRun.room_changes`` or ``changes_from_truth(rows)``.
        detections: Per robot, its transitions, each with ``seq`` and ``boundary_seq``.
        positions: (robot, seq) -> (x, y), for the door figures (``positions_from_truth``).
        doors: Door centres (x, y), for the door figures.
        tolerance_frames: Half-width of the matching windows, frames.
        distance_m: How near a door a detection must be to count as at a door.

    Returns:
        The figures; ratios are None where their denominator is zero.
    """
    if tolerance_frames < 0 or distance_m < 0:
        msg = f"tolerance_frames and distance_m must be >= 0, got {tolerance_frames}, {distance_m}"
        raise ValueError(msg)
    tol = tolerance_frames
    true_seqs: dict[str, list[int]] = {}
    for change in changes:
        true_seqs.setdefault(str(_get(change, "robot")), []).append(int(_get(change, "seq")))
    found: dict[str, list[tuple[int, int]]] = {
        str(robot): [(int(_get(t, "seq")), int(_get(t, "boundary_seq"))) for t in items]
        for robot, items in detections.items()
    }
    latencies: list[int] = []
    hit = hit_boundary = 0
    for robot, seqs in true_seqs.items():
        seqs.sort()
        mine = found.get(robot, [])
        for c, following in zip(seqs, [*seqs[1:], math.inf], strict=True):
            hit += any(c <= s <= c + tol for s, _ in mine)
            hit_boundary += any(abs(b - c) <= tol for _, b in mine)
            before_next = [s for s, _ in mine if c <= s < following]
            if before_next:
                latencies.append(min(before_next) - c)
    total_changes = sum(len(seqs) for seqs in true_seqs.values())
    total_found = sum(len(items) for items in found.values())

    def near_change(robot: str, s: int) -> bool:
        return any(abs(s - c) <= tol for c in true_seqs.get(robot, ()))

    door_points = list(doors) if doors is not None else None

    def near_door(robot: str, s: int) -> bool | None:
        if positions is None or door_points is None or (robot, s) not in positions:
            return None
        x, y = positions[(robot, s)]
        return any(math.hypot(dx - x, dy - y) <= distance_m for dx, dy in door_points)

    pairs = [(robot, s, b) for robot, items in found.items() for s, b in items]
    at_door = [near_door(robot, b) for robot, _, b in pairs]
    at_door_seq = [near_door(robot, s) for robot, s, _ in pairs]
    return Score(
        changes=total_changes,
        transitions=total_found,
        tolerance_frames=tol,
        distance_m=distance_m,
        recall=_ratio(hit, total_changes),
        recall_boundary=_ratio(hit_boundary, total_changes),
        recall_any=_ratio(len(latencies), total_changes),
        precision=_ratio(sum(near_change(r, s) for r, s, _ in pairs), total_found),
        precision_boundary=_ratio(sum(near_change(r, b) for r, _, b in pairs), total_found),
        precision_door=_share(at_door),
        precision_door_at_seq=_share(at_door_seq),
        latency_mean=statistics.fmean(latencies) if latencies else None,
        latency_median=statistics.median(latencies) if latencies else None,
        latency_max=max(latencies) if latencies else None,
    )


def changes_from_truth(rows: Iterable[Any]) -> list[dict[str, Any]]:
    """Derive the room changes from per-frame truth rows (``robot``, ``seq``, ``room``).

    Rows may be in any order; each robot's rows are taken in seq order, and a change is
    the first frame whose room differs from the previous frame's.
    """
    by_robot: dict[str, list[tuple[int, int]]] = {}
    for row in rows:
        robot = str(_get(row, "robot"))
        by_robot.setdefault(robot, []).append((int(_get(row, "seq")), int(_get(row, "room"))))
    changes = []
    for robot, items in by_robot.items():
        items.sort()
        for (_, before), (seq, room) in itertools.pairwise(items):
            if room != before:
                changes.append({"robot": robot, "seq": seq, "from_room": before, "to_room": room})
    return changes


def positions_from_truth(rows: Iterable[Any]) -> dict[tuple[str, int], tuple[float, float]]:
    """Map (robot, seq) to the true (x, y) of per-frame truth rows."""
    return {
        (str(_get(row, "robot")), int(_get(row, "seq"))): (
            float(_get(row, "x")),
            float(_get(row, "y")),
        )
        for row in rows
    }


def _get(record: Any, name: str) -> Any:
    if isinstance(record, Mapping):
        return record[name]
    return getattr(record, name)


def _ratio(part: int, whole: int) -> float | None:
    return part / whole if whole else None


def _share(flags: list[bool | None]) -> float | None:
    known = [flag for flag in flags if flag is not None]
    return _ratio(sum(known), len(known)) if known and len(known) == len(flags) else None

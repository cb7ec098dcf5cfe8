"""``RoomParams``: how a ``RoomTracker`` sizes its window, cuts it and confirms a cut.

The rules the fields tune are in ``lessmap.core.rooms.tracker``'s docstring. Every size is
counted in evidence (the view's own change), never in frames or seconds, so one setting
serves a robot sending 2 frames a second and one sending 30, a laser and a camera.
"""

from __future__ import annotations

from dataclasses import dataclass

from lessmap.core.errors import GraphError


@dataclass(frozen=True, slots=True, kw_only=True)
class RoomParams:
    """How a ``RoomTracker`` finds and names rooms (rules in ``lessmap.core.rooms.tracker``)."""

    # Rule 1: a window side spans the frames over which the view keeps this share of the
    # CovRate of frames seen from the same place, learnt from the stream; so its length
    # follows speed, rate and range. 0.65 (0.6 of CovRate at 9 detections in 10): a longer
    # view of the area behind steadies the cut (fewer false peaks in rooms).
    window_similarity: float = 0.65
    # The share is of the stream's own ceiling: a detector that misses more landmarks lowers
    # every CovRate, not how far the view reaches. False: of CovRate 1 (sessions saved so).
    window_relative: bool = True
    window_min_frames: int = 2  # a pair: at 2 frames a second, 3 frames put decisions 1.5 m late
    window_max_frames: int = 30  # the memory a side may take, and the decision's lag
    lag_smoothing: float = 0.02  # weight of a new frame in the learnt lag profile
    # The newer half's frames, as a share of the older half's: 0.35 of the longer older half
    # keeps the newer half, and so the decision's lag, as short as 0.5 of a 0.7 window.
    ahead_share: float = 0.35
    # Rule 2: the cut of a window, (within-side similarity) - (across-side similarity).
    cut_min: float = 0.1
    # A peak must stay the highest over this share of a newer half's cuts after it: a door
    # looked at from the room shows first, the door passed shows more.
    settle_share: float = 0.0
    # Rule 3: a cut is a room change only when the new side is not the segment's own.
    known_share: float = 0.8  # of the new half's features, the area's own at least this
    # ... unless the cut reaches sure_cut over at least sure_features new-half features:
    # a door's view seen from inside, not a glimpse through it or a turn among a few poles.
    sure_cut: float = 0.12
    sure_features: int = 10
    min_side_features: int = 5  # distinct features on each side of a change
    # Rule 4: the area entered, when the new side's features are nearly all an area's. A
    # wrong name merges two rooms, a missed one only splits a room: the bar is high.
    revisit_overlap: float = 0.8
    # Rule 5: sightings (feature, area) the area models hold at most; 0: no bound.
    max_area_sightings: int = 100_000

    def __post_init__(self) -> None:
        checks = {
            "window_similarity": 0.0 < self.window_similarity < 1.0,
            "window_min_frames": self.window_min_frames >= 2,
            "window_max_frames": self.window_max_frames >= self.window_min_frames,
            "lag_smoothing": 0.0 < self.lag_smoothing <= 1.0,
            "ahead_share": 0.0 < self.ahead_share <= 1.0,
            "cut_min": self.cut_min > 0.0,
            "settle_share": 0.0 <= self.settle_share <= 2.0,
            "known_share": self.known_share > 0.0,
            "sure_cut": self.sure_cut > 0.0,
            "sure_features": self.sure_features >= 1,
            "min_side_features": self.min_side_features >= 1,
            "revisit_overlap": 0.0 < self.revisit_overlap <= 1.0,
            "max_area_sightings": self.max_area_sightings >= 0,
        }
        for name, ok in checks.items():
            if not ok:
                msg = f"invalid room parameter {name}={getattr(self, name)!r}"
                raise GraphError(msg)

"""``AreaParams``: how an ``AreaTracker`` pools, confirms, recognises and names areas.

The rules the fields tune are in ``lessmap.core.areas.tracker``'s module docstring; each field's
comment says what it does and why its default; ``docs/tuning/areas.md`` holds the figures,
measured with ``python -m lessmap.evaluation.studies.areabench``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Final

from lessmap.core.errors import GraphError
from lessmap.core.paper.params import PartitionParams

#: ``AreaParams.period_steps`` for a stream that leaves out its empty frames.
EMPTY_OMITTED_PERIOD_STEPS: Final = 16


def _default_proposal() -> PartitionParams:
    # Looser than the paper's (0.25, 0.2) so a first visit is found within a few frames of the
    # door (rules 3c, 3d and 6 drop or hold what it proposes inside an area). No rule reads
    # the proposer's closed submaps, so it keeps none: that halves an old session's checkpoint.
    return PartitionParams(ncut_min=0.44, lambda2_min=0.4, keep_closed_submaps=0)


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaParams:
    """How an ``AreaTracker`` pools, confirms, recognises and names areas.

    The rules are in ``lessmap.core.areas.tracker``'s module docstring. The figures behind
    each default, and the alternatives tried, are in ``docs/tuning/areas.md``.
    """

    proposal: PartitionParams = field(default_factory=_default_proposal)
    # Rule 1: a pool closes at this many distinct features or frames, so a sparse sensor's
    # one- or two-feature frames propose no fragments; larger pools cost recall.
    pool_min_features: int = 4
    pool_max_frames: int = 4
    # Rule 3a: no closed area is smaller than this many features.
    min_area_features: int = 5
    # Rule 4: share of the new side's features an area must have seen to be entered again;
    # higher adds transitions in open rooms.
    revisit_overlap: float = 0.5
    confirm_frames: int = 12  # rule 3a: a proposal not confirmed within this many frames
    history_frames: int = 4000  # frames of the current segment kept (oldest go first)
    # Rule 9: sightings (feature, area) the area models hold at most, so a session's memory
    # does not grow with every area it ever opened; far above any data set's. 0: no bound.
    max_area_sightings: int = 100_000
    # Rule 3b: empty frames before a boundary that make it blind. One is enough: no building
    # has one before a door, while an open room wider than the sensor's range has many.
    blind_frames: int = 1
    # Rule 3b: also blind, a run of ``blind_span`` empty frames from ``blind_margin``
    # non-empty frames before the boundary on (the robot glimpsed a wall on its way across).
    blind_span: int = 3
    blind_margin: int = 3
    # Rule 3b: stamp steps whose median is a stream's period, to read its gaps as empty
    # frames. 0 (stamps unread) unless a stream declares it omits its empty frames
    # (``for_stream``): elsewhere a gap is a stall or a loss, and may fall at a door.
    period_steps: int = 0
    # Rule 3c: share of the new side's sightings familiar to the current area that makes a
    # proposal a move within the area; lower names areas falsely, higher splits open rooms.
    stay_share: float = 0.5
    # Rule 3c: a feature is familiar when seen in this share of the area's frames ...
    familiar_rate: float = 0.1
    # ... or in this share of the mean count of its features, if less: with a sparse sensor
    # every feature's rate is low, and no feature of a room would pass ``familiar_rate``.
    familiar_relative: float = 0.15
    # Rule 3c: non-empty frames before the boundary left out of the familiar test, where a
    # doorway shows the next room; a short first stay would otherwise make it familiar.
    familiar_margin_frames: int = 3
    # Rule 3d: a spectral proposal above this Ncut is weak and must span ``weak_frames``
    # frames first: a doorway seen through (270°) proposes early, a 360° door late.
    weak_ncut: float = 0.4
    weak_frames: int = 6
    # Rules 3a, 3c: ``confirm_frames`` and ``familiar_margin_frames`` are frames of a stream
    # whose view keeps ``view_share`` of its CovRate from one place for ``view_frames``
    # frames (the generated buildings at 2 frames a second, where they were measured). With
    # ``spans_in_views`` they grow by the stream's own such frames, learnt from its lag
    # profile (``lessmap.core.lagprofile``): at 10 frames a second a door takes five times
    # the frames it takes at 2. A faster view keeps the measured counts (the tracker's
    # ``_in_views``). ``weak_frames`` stays in frames: scaled, it held the late proposals of
    # 360° sensors so long that areabench's 360° recall fell to 84 %. False: spans in frames
    # (sessions saved before version 11).
    spans_in_views: bool = True
    view_share: float = 0.65
    view_frames: int = 8
    # The lag profile looks this many non-empty frames back, on one frame in
    # ``view_every`` (a row of set intersections each): ~6 intersections a frame.
    view_max_lag: int = 48
    view_every: int = 8
    # Rule 5: non-empty frames that must favour a known area; fewer recognise a doorway
    # before the door, more recognise a 360° return late.
    recognise_frames: int = 3
    # Rule 5: mean log-likelihood ratio per frame, in nats, that recognition needs; lower
    # adds transitions in open rooms, higher misses returns.
    recognise_llr: float = 10.0
    # Rule 6: rate overlap at which two areas are one seen in two parts and merge; lower
    # merges neighbouring rooms.
    merge_overlap: float = 0.3
    # Rule 7: the segment entered starts at most this many frames after the area boundary,
    # where the two sides share most features, so both submaps keep the door's landmarks.
    seam_frames: int = 6
    # Rule 10: features kept a frame at most, by a subsample of ids (``sampling.py``):
    # a camera's 1,000 features cost ~15 times the pairs of 256, and a CovGraph to match;
    # a frame under it, and a stream whose frames all are, is taken whole. 0: keep all.
    max_features_kept: int = 256

    def __post_init__(self) -> None:
        checks = {
            "pool_min_features": self.pool_min_features >= 1,
            "pool_max_frames": self.pool_max_frames >= 1,
            "min_area_features": self.min_area_features >= 1,
            "revisit_overlap": 0.0 < self.revisit_overlap <= 1.0,
            "confirm_frames": self.confirm_frames >= 0,
            "history_frames": self.history_frames >= 1,
            "max_area_sightings": self.max_area_sightings >= 0,
            "blind_frames": self.blind_frames >= 0,
            "blind_span": self.blind_span >= 0,
            "blind_margin": self.blind_margin >= 0,
            "period_steps": self.period_steps >= 0,
            "stay_share": self.stay_share > 0.0,
            "familiar_rate": 0.0 < self.familiar_rate <= 1.0,
            "familiar_relative": 0.0 <= self.familiar_relative <= 1.0,
            "familiar_margin_frames": self.familiar_margin_frames >= 0,
            "weak_ncut": self.weak_ncut >= 0.0,
            "weak_frames": self.weak_frames >= 0,
            "recognise_frames": self.recognise_frames >= 0,
            "recognise_llr": self.recognise_llr >= 0.0,
            "merge_overlap": self.merge_overlap > 0.0,
            "seam_frames": self.seam_frames >= 0,
            "view_share": 0.0 < self.view_share < 1.0,
            "view_frames": self.view_frames >= 1,
            "view_max_lag": self.view_max_lag >= 2,
            "view_every": self.view_every >= 1,
            "max_features_kept": self.max_features_kept >= 0,
        }
        for name, ok in checks.items():
            if not ok:
                msg = f"invalid area parameter {name}={getattr(self, name)!r}"
                raise GraphError(msg)

    def for_stream(self, *, empty_frames_omitted: bool) -> AreaParams:
        """Return these parameters for a stream that sends its empty frames or leaves them out.

        Only a stream declared to leave them out has its stamp gaps read as blindness
        (rule 3b); the paper method reads no stamps at all.
        """
        steps = EMPTY_OMITTED_PERIOD_STEPS if empty_frames_omitted else 0
        return self if steps == self.period_steps else replace(self, period_steps=steps)

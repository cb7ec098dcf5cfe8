"""``AreaParams``: how an ``AreaTracker`` pools, confirms, recognises and names areas.

The rules the fields tune are in ``lessmap.core.areas.tracker``'s module docstring; each field's
comment says why its default is what it is, measured with
``python -m lessmap.evaluation.studies.areabench``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Final

from lessmap.core.errors import GraphError
from lessmap.core.paper.params import PartitionParams

#: ``AreaParams.period_steps`` for a stream that leaves out its empty frames.
EMPTY_OMITTED_PERIOD_STEPS: Final = 16


def _default_proposal() -> PartitionParams:
    # Looser than the paper's (0.25, 0.2), so a first visit is found within a few frames of
    # the door; rules 3c, 3d and 6 drop or hold what it proposes inside an area. With a 360°
    # sensor the room left behind stays in view through the door and the Ncut of the door
    # falls slowly, 0.5 to 0.4 over 5-15 frames after it: at 0.4 (and no rule 3d) 360°
    # sparse R / P 94.3 / 96.2%, held-out 90.2 / 92.4% (96.8 / 96.8, 93.5 / 95.2); at 0.44
    # without rule 3d, 270° sparse R 93.3% and 3.8% false area names. With rule 3d at 4
    # frames, 0.43: 360° sparse R 97.0%, held-out 93.0%; 0.45: 96.5%, 270° sparse held-out
    # 2.2% false names. λ2 never binds here: (0.45, 0.4) decides as (0.45, 0.45).
    # The proposer's own closed submaps are read by no rule (``AreasSegmenter`` keeps the
    # segments): keeping none halves an old session's memory of them and its checkpoint
    # (dlr's end 80 -> 67 KB, a 3,000-frame simulated robot 104 -> 86 KB).
    return PartitionParams(ncut_min=0.44, lambda2_min=0.4, keep_closed_submaps=0)


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaParams:
    """How an ``AreaTracker`` pools, confirms, recognises and names areas.

    The rules are in ``lessmap.core.areas.tracker``'s module docstring.

    Figures in the comments come from ``python -m lessmap.evaluation.studies.areabench --seeds 5``
    with the one field changed from the defaults (the defaults' figure in parentheses);
    R / P are recall / precision within ±8 frames, "per 10 min" counts transitions per robot
    per 10 minutes, "open rooms" are the simulated rooms with no doors. The figures of the
    fields before ``weak_ncut`` were measured with proposals at Ncut 0.4 and no rule 3d.
    """

    proposal: PartitionParams = field(default_factory=_default_proposal)
    # Rule 1. A pool closes with this many distinct features or frames. 6 / 4 (the first
    # version): 360° sparse R / P 92.0 / 93.9% (94.3 / 96.2), mrclam6 2.99 and mrclam1_w1s
    # 2.50 per 10 min (2.42, 1.78); 1 / 1, no pooling: 270° sparse R 94.0% (98.8), 12-16 m
    # open rooms at 270° 4.32 per 10 min (3.04).
    pool_min_features: int = 4
    pool_max_frames: int = 4
    # Rule 3a: the bound on a closed area (no closed submap below 5 features).
    min_area_features: int = 5
    # Rule 4. 0.4 and 0.6 decide the buildings alike (revisits 100 / 99.7% recognised); 0.6
    # adds transitions in open rooms and on mrclam1_w1s (2.02 per 10 min, 1.78).
    revisit_overlap: float = 0.5
    confirm_frames: int = 12  # rule 3a: a proposal not confirmed within this many frames
    history_frames: int = 4000  # frames of the current segment kept (oldest go first)
    # Rule 9. Sightings (feature, area) the area models hold at most: a session's memory
    # must not grow with every area it ever opened (a robot making new areas of new
    # features without end would take the instance's memory). Above it the smallest areas
    # other than the current one forget their features, down to 3/4 of it. Measured at
    # most: dlr 902, a simulated 8-room building (seed 0, 270° and 360°) 354 per robot,
    # MRCLAM 23, so no data set comes near it; 0: no bound.
    max_area_sightings: int = 100_000
    # Rule 3b. No simulated building has an empty frame before a door, so one is enough; 0
    # (off): 12-16 m open rooms, where a 5 m sensor sees nothing mid-room, 18.10 / 16.82 /
    # 3.36 per 10 min at 270° dense / 360° dense / 270° sparse (3.04 / 1.84 / 0.56).
    blind_frames: int = 1
    # Also blind: a run of ``blind_span`` empty frames from ``blind_margin`` non-empty frames
    # before the boundary on (the robot glimpsed a wall on its way across). 0 (off): 12-16 m
    # open rooms at 270° / 360° dense 1.44 / 0.64 per 10 min, held-out seeds 5-9 1.20 /
    # 1.52 (0.96 / 0.32, held-out 0.48 / 0.64); no building figure moves, seeds 0-4 or 5-9,
    # at 2 to 4 frames; 2: dlr 85 transitions (86). A margin of 0 frames: 360° dense 0.64.
    blind_span: int = 3
    blind_margin: int = 3
    # A stream may leave out its empty frames (MRCLAM's frames are a robot's sightings that
    # share a stamp): then blindness shows only as a gap between stamps, read as the frames
    # missing at the stream's period, the median of its last ``period_steps`` stamp steps.
    # 0 (the default): stamps are not read, because a stream that sends its empty frames
    # shows a gap only when its computer stalled or frames were lost, and a robot stamped at
    # publish time that stalls at a door would lose that transition. A source declares that
    # it leaves out its empty frames (``for_stream``; ``serve --empty-frames-omitted FLEET``,
    # ``segment --empty-frames-omitted``), and then gets ``EMPTY_OMITTED_PERIOD_STEPS``.
    # No simulated stream and no dlr stamp (frame indices) has a gap. Read at 16 steps:
    # mrclam6 0.00 per 10 min (1.28 unread: robot 3 turns from one wall of the arena to the
    # other seeing nothing for 2-29 s, and such turns made 7 of its 8 transitions),
    # mrclam1_w1s 0.16 (0.32). The 12-16 m open rooms without their empty frames: 0.96 /
    # 0.32 / 0.08 per 10 min at 270° dense / 360° dense / 270° sparse (16.02 / 16.10 / 4.24
    # unread; with the empty frames kept, 0.96 / 0.32 / 0.16).
    period_steps: int = 0
    # Rule 3c. Above 1 (off): 8-10 m open rooms 7.93 per 10 min (1.12), 360° sparse revisits
    # 90.0% recognised (100), dlr 131 transitions (102); 0.4: 270° dense R 95.5% and 3.6%
    # false area names (98.0, 1.0%); 0.6: 12-16 m open rooms 4.48 per 10 min (3.04).
    stay_share: float = 0.5
    # 0.2: open rooms 2.00 / 1.28 / 1.60 per 10 min at 8-10 m (1.12 / 0.72 / 0.72).
    familiar_rate: float = 0.1
    # Or seen in this share of the mean count of the area's features, whichever is less: with
    # a sparse sensor every feature's rate is low (mrclam6: 1.7 of 15 landmarks per frame, so
    # 0.11 on average) and no feature of one room passed 0.1. 0 (off): mrclam6 2.42 per 10
    # min (1.28), 12-16 m open rooms 3.04 / 1.84 / 0.56 (1.76 / 0.64 / 0.16), held-out
    # 3.20 / 2.16 / 1.04 (1.36 / 1.52 / 0.40); 0.25: mrclam1_w1s 1.29 (0.97); 0.1: dlr 82
    # transitions (89). Buildings: 270° sparse R 98.8% at 0 (98.0), held-out 360° dense R
    # 96.0% (95.2).
    familiar_relative: float = 0.15
    # A short first stay would keep the next room, seen through the door, as familiar: 0
    # frames gives 270° sparse R 96.0% and 2.4% false names (98.8, 0.0%); 8 frames gives
    # 12-16 m open rooms at 270° 4.00 per 10 min (3.04) and dlr 113 transitions (102).
    familiar_margin_frames: int = 3
    # Rule 3d. A spectral proposal with an Ncut above ``weak_ncut`` is weak: it waits until
    # the frames from its boundary span ``weak_frames`` frames. A doorway seen before the
    # door (270°) proposes early; a 360° door is proposed late, when its new side has lasted.
    # 0 frames (off): 270° sparse R 93.3% and 3.8% false area names (96.0, 1.7%), 270° dense
    # 1.9% (0.0); 4: 270° sparse held-out 97.8% (99.2); 8: 360° sparse R / P 94.5 / 94.5%.
    weak_ncut: float = 0.4
    weak_frames: int = 6
    # Rule 5. 0 frames (off): 360° dense R / P 89.8 / 90.5%, 360° sparse 79.6 / 85.3%
    # (97.8 / 97.8, 94.3 / 96.2); 2 frames recognise a doorway before the door: 270° dense
    # R 94.3%; 4 frames: 360° sparse R 94.0%, 12-16 m open rooms unchanged.
    recognise_frames: int = 3
    # 5 nats: mrclam1_w1s 2.83 per 10 min (1.78), 12-16 m open rooms 3.92 (3.04); 20 nats:
    # 360° sparse R 89.6%.
    recognise_llr: float = 10.0
    # Rule 6. Above 1 (off): 8-10 m open rooms 10.17 / 4.64 / 1.52 per 10 min (1.12 / 0.72 /
    # 0.72), mrclam1_w1s 3.23 (1.78); no building figure moves. 0.25: 0.96 for the first,
    # but a room merged into its neighbour at held-out seeds 5-9 (360° dense R 95.2%,
    # 96.0 at 0.3); 0.2: 360° dense R 93.8%, revisits 96.7%.
    merge_overlap: float = 0.3
    # Rule 7. The segment entered (the submap reported) starts at most this many frames after
    # the area boundary, where the two sides share most features. 0 (off): dlr e 1.474% at
    # 87 submaps (1.022%; fixed frames 1.134%), 270° / 360° dense 403 / 403 transitions and
    # revisits 99.0 / 99.3% recognised (402 / 402, 100 / 100; held-out seeds unchanged);
    # 4: e 1.091%; 8: 1.013%. The area boundary moved instead, 4 frames either way: e 0.931%
    # but 270° sparse 2.4% false area names and 360° sparse R 94.8%. Boundaries moved to the
    # fewest shared features within 3-10 frames (the paper's cut) give e 1.64-1.73%: a
    # landmark seen on both sides keeps its pairs.
    seam_frames: int = 6

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

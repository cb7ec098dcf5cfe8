"""Areas on top of LESS-mapping: pooled evidence, confirmed splits, recognised revisits.

``AreaTracker`` drives a paper ``Partitioner`` as proposer (``docs/design/area-rules.md``; no I/O):

1. Minimum evidence: frames are pooled before they reach the proposer.
2. Proposals: the paper's test, with looser thresholds, names a boundary frame.
3. Confirmation: (a) enough features, (b) not blind, (c) not its area's, (d) lasted; (e) in views.
4. Which area: a known area that saw enough of the new side is entered again, else a new one.
5. Recognition: when recent frames fit a known area's profile better, the robot is back there.
6. Merging: a change into a known area overlapping the current one merges them, no transition.
7. Area model: per-feature frame counts per area; the segment entered starts at the seam.
8. State: everything a later decision reads round-trips through the snapshot bit for bit.
9. Bounded models: above ``max_area_sightings`` the smallest other areas forget their features.
10. Sampling: a frame keeps at most ``max_features_kept`` features, the same ids in each.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core import lagprofile
from lessmap.core.areas import rules
from lessmap.core.areas.events import (
    AreaReason,
    AreaTransition,
    Candidate,
    Rule,
    segment_transition,
)
from lessmap.core.areas.model import merge, move
from lessmap.core.areas.params import EMPTY_OMITTED_PERIOD_STEPS, AreaParams
from lessmap.core.areas.pool import Pool
from lessmap.core.areas.profile import (
    Frame,
    Profile,
    count_pair,
    distinct,
    profile,
    rate_overlap,
    tally,
    without,
)
from lessmap.core.areas.sampling import FeatureSampler
from lessmap.core.errors import StaleFrameError
from lessmap.core.paper.partitioner import Partitioner
from lessmap.core.paper.submaps import Reason, Submap

if TYPE_CHECKING:
    from collections.abc import Iterable

#: Weight of a new row in the lag profile once it has seen 50 (rules 3a, 3c): a slow mean.
LAG_SMOOTHING = 0.02

__all__ = [
    "EMPTY_OMITTED_PERIOD_STEPS",
    "AreaParams",
    "AreaReason",
    "AreaTracker",
    "AreaTransition",
    "Candidate",
    "Frame",
    "Profile",
    "Rule",
    "profile",
    "rate_overlap",
]


class AreaTracker:
    """Areas of one robot session from its frames. No I/O."""

    def __init__(self, params: AreaParams | None = None) -> None:
        """Start an empty session in area 0."""
        self.params = params if params is not None else AreaParams()
        self.proposer = Partitioner(self.params.proposal)
        self.sampler = FeatureSampler(self.params.max_features_kept)  # rule 10
        p = self.params
        self.pool = Pool(p.pool_min_features, p.pool_max_frames, p.proposal.history_frames + 1)
        # the current segment (frames since the last transition)
        self.segment_id = 0
        self.segment_first_seq: int | None = None
        self.segment_frame_count = 0
        self.segment_counts: dict[int, int] = {}  # feature -> frames of the segment
        self.frames: deque[Frame] = deque(maxlen=self.params.history_frames)
        # rule 3b: the last stamp steps, and (frame, frames missing before it) of kept frames
        self.steps: deque[float] = deque(maxlen=self.params.period_steps or None)
        self.gaps: deque[tuple[int, int]] = deque()
        # areas (rule 7); a merged area keeps its slot, empty, and its entry in ``merged``
        self.areas: list[dict[int, int]] = [{}]
        self.area_frames: list[int] = [0]  # non-empty frames per area
        self.merged: dict[int, int] = {}  # merged area -> the area it merged into
        self.sightings = 0  # entries of ``areas`` (rule 9), derived: not in the snapshot
        self.current = 0
        self.candidate: Candidate | None = None
        self.last_seq: int | None = None
        self.last_stamp_s = 0.0
        self.frames_applied = 0
        self.transitions = 0
        self._profiles: dict[int, Profile | None] = {}  # derived from areas (rule 8)
        # rules 3a, 3c with spans_in_views: mean CovRate of non-empty frames d apart (d - 1)
        self.lag_mean = np.zeros(p.view_max_lag, dtype=np.float64)
        self.lag_seen = np.zeros(p.view_max_lag, dtype=np.int64)

    # -- read ------------------------------------------------------------------------------

    @property
    def area_count(self) -> int:
        """Areas opened so far and not merged into another (the current one included)."""
        return len(self.areas) - len(self.merged)

    def area_of(self, area: int) -> int:
        """The area an id stands for now: itself, or the area it was merged into."""
        while area in self.merged:
            area = self.merged[area]
        return area

    def area_features(self, area: int) -> tuple[int, ...]:
        """The features an area's frames have seen, ascending."""
        return tuple(sorted(self.areas[self.area_of(area)]))

    def current_segment(self) -> Submap:
        """The open segment: its frames so far and their features."""
        first = self.segment_first_seq
        return Submap(
            id=self.segment_id,
            first_seq=first if first is not None else 0,
            last_seq=self.last_seq if self.last_seq is not None else 0,
            frame_count=self.segment_frame_count,
            features=tuple(sorted(self.segment_counts)),
        )

    # -- frames ----------------------------------------------------------------------------

    def observe(self, seq: int, stamp_s: float, features: Iterable[int]) -> AreaTransition | None:
        """Add one frame and settle at once; return the area change it confirms, if any.

        Raises:
            StaleFrameError: seq is not greater than the last seq.
            GraphError: a feature ID is not an integer.
        """
        self.add(seq, stamp_s, features)
        return self.settle()

    def add(self, seq: int, stamp_s: float, features: Iterable[int]) -> None:
        """Count one frame in: the segment's and area's sightings, the pool, the proposer's graph.

        The tests that can change the area (the proposer's Eq. 4, rules 3-6) wait for
        ``settle``. Called after every frame, the two are ``observe``; a service behind its
        load settles once for several frames, as the paper's partitioner decides once for
        several, and then the tests run once (they were most of the method's cost, and
        would not shrink under load if each frame ran them).

        Raises:
            StaleFrameError: seq is not greater than the last seq.
            GraphError: a feature ID is not an integer.
        """
        if self.last_seq is not None and seq <= self.last_seq:
            msg = f"frame seq {seq} is not after the last applied seq {self.last_seq}"
            raise StaleFrameError(msg)
        p = self.params
        seen = self.sampler.keep(distinct(seq, features))
        self._step(seq, float(stamp_s))
        self.last_seq = seq
        self.last_stamp_s = float(stamp_s)
        self.frames_applied += 1
        if self.segment_first_seq is None:
            self.segment_first_seq = seq
        self.segment_frame_count += 1
        if seen and p.spans_in_views and seq % p.view_every == 0:
            self._learn_view(seen)
        self.frames.append((seq, seen))
        self._forget_gaps()
        if seen:
            counts = self.areas[self.current]
            known = len(counts)
            count_pair(self.segment_counts, counts, seen)
            self.sightings += len(counts) - known
            self.area_frames[self.current] += 1
            self._profiles.pop(self.current, None)
            self._bound_models()
        closed = self.pool.add(seq, seen)
        if closed is not None:
            self.proposer.apply_distinct(closed[0], self.last_stamp_s, closed[1])

    def settle(self) -> AreaTransition | None:
        """Run the tests on the frames added since the last settle; return the change found.

        The proposer decides once on the pools closed meanwhile (rules 1, 2), then a pending
        proposal is confirmed, kept or dropped (rules 3, 4, 6) and the last frame, if it saw
        anything, may be recognised (rule 5), all at the last frame added. Call it once after
        the frames it covers: it tests the last frame again if called twice.
        """
        change = self._settle()
        self._bound_models()
        return change

    def _settle(self) -> AreaTransition | None:
        seq = self.last_seq
        if seq is None:
            return None
        self._propose(seq)
        if self.candidate is not None:
            change = self._confirm(seq)
            if change is not None:
                return change
        if self.frames and self.frames[-1][1] and self.params.recognise_frames:
            return self._recognise(seq)
        return None

    def _step(self, seq: int, stamp_s: float) -> None:
        """Note the frames missing before this one, at the stream's period (rule 3b).

        A stream without its empty frames (a frame only when something is seen) shows the
        robot's blindness only in its stamps.
        """
        if not self.params.period_steps or self.last_seq is None:
            return
        step = stamp_s - self.last_stamp_s
        if step <= 0.0:
            return  # equal stamps tell no period
        if self.steps:
            missing = rules.missing_frames(step, self.steps)
            if missing:
                self.gaps.append((seq, missing))
        self.steps.append(step)

    def _learn_view(self, seen: tuple[int, ...]) -> None:
        """Learn the lag profile from one frame's CovRate to the non-empty frames before it."""
        here = set(seen)
        row: list[float] = []
        for _, earlier in reversed(self.frames):
            if earlier:
                row.append(len(here.intersection(earlier)) / min(len(here), len(earlier)))
                if len(row) == len(self.lag_mean):
                    break
        lagprofile.learn(self.lag_mean, self.lag_seen, np.array(row), LAG_SMOOTHING)

    def _in_views(self, frames: int) -> int:
        """A span of ``frames`` at the reference view speed, in this stream's frames.

        Never fewer than ``frames``: a view that changes faster than the reference's (2
        frames a second, a short range) keeps the spans that were measured, because a
        decision on fewer frames rests on fewer detections, however far they reach.
        """
        p = self.params
        if not p.spans_in_views:
            return frames
        bar = p.view_share * lagprofile.ceiling(self.lag_mean, self.lag_seen)
        view = lagprofile.first_lag_at(self.lag_mean, self.lag_seen, bar, 1, p.view_max_lag)
        return frames if view is None else max(frames, round(frames * view / p.view_frames))

    def _forget_gaps(self) -> None:
        """Drop the gaps before the first kept frame (no rule looks there)."""
        first = self.frames[0][0] if self.frames else None
        while self.gaps and (first is None or self.gaps[0][0] < first):
            self.gaps.popleft()

    def _propose(self, seq: int) -> None:
        """Let the proposer decide on the pools it was handed since (rules 1, 2)."""
        proposal = self.proposer.decide()
        if proposal is not None:
            self.candidate = Candidate(
                boundary_seq=self.pool.start_of(proposal.boundary_seq, seq),
                seq=seq,
                reason=proposal.reason,
                ncut=proposal.ncut,
                lambda2=proposal.lambda2,
                boundary_features=proposal.boundary_features,
            )
        # The proposer's boundaries fall in its kept history only: older pools' first frames
        # would only cost memory and checkpoint bytes (2,000 of them once a session is old).
        oldest = self.proposer.oldest_boundary_seq
        if oldest is not None:
            self.pool.forget_before(oldest)

    # -- rules 3, 4: a proposal ------------------------------------------------------------

    def _confirm(self, seq: int) -> AreaTransition | None:
        """Confirm, keep waiting on, or drop the pending proposal (rules 3, 4, 6)."""
        candidate = self.candidate
        assert candidate is not None
        boundary = candidate.boundary_seq
        p = self.params
        weak = candidate.ncut is not None and candidate.ncut > p.weak_ncut
        if weak and seq - boundary < p.weak_frames:  # rule 3d
            if seq - candidate.seq >= self._in_views(p.confirm_frames):
                self.candidate = None
            return None
        after, before, moved = rules.sides(self.frames, self.segment_counts, boundary)
        minimum = self.params.min_area_features
        if len(before) < minimum:
            self.candidate = None  # no closed area is this small: the segment goes on
            return None
        if len(after) < minimum:
            if seq - candidate.seq >= self._in_views(p.confirm_frames):
                self.candidate = None
            return None
        share = rules.familiar_share(
            self.frames,
            self.areas[self.current],
            self.area_frames[self.current],
            boundary,
            after,
            rate=p.familiar_rate,
            margin=self._in_views(p.familiar_margin_frames),
            relative=p.familiar_relative,
        )
        if self._blind(boundary) or share >= p.stay_share:
            self.candidate = None
            return None
        known, overlap = rules.known_area(
            self.areas, self._live(), self.current, after, p.revisit_overlap
        )
        if known is not None and self._merges_with(known, after, moved):
            self.candidate = None
            return None
        return self._enter(candidate, seq, known, overlap, Rule.SPLIT)

    # -- rule 5: recognition ---------------------------------------------------------------

    def _recognise(self, seq: int) -> AreaTransition | None:
        """Enter the known area the last frames fit better than the current one, if any."""
        first = self.segment_first_seq
        window = rules.last_nonempty(self.frames, self.params.recognise_frames)
        if first is None or window is None or window[0][0] <= first:
            return None
        if not self._recognisable():
            return None  # no known area to fit better: the profiles below cannot matter
        leave, left = tally(window)
        # Only the window's frames are weighed against known areas, so the current area's
        # profile needs only their features' gains (rule 5 costs a profile every frame).
        counts, frames = self.areas[self.current], self.area_frames[self.current]
        here = profile(counts, frames, leave, left, only=leave)
        if here is None:
            return None
        best = rules.best_fit(
            window,
            here,
            self._live(),
            lambda area: self._profile(area) if area != self.current else None,
            self.params.recognise_llr,
        )
        if best is None:
            return None
        there = self._profile(best)
        assert there is not None
        here = profile(counts, frames, leave, left)  # all gains: walk_back reads earlier frames
        assert here is not None
        boundary = rules.walk_back(self.frames, window[0][0], first, there, here)
        after, before, moved = rules.sides(self.frames, self.segment_counts, boundary)
        minimum = self.params.min_area_features
        if len(before) < minimum or len(after) < minimum:
            return None
        if self._blind(boundary):
            return None
        if self._merges_with(best, after, moved):
            return None
        candidate = Candidate(
            boundary_seq=boundary,
            seq=seq,
            reason=Reason.SPECTRAL,
            ncut=None,
            lambda2=None,
            boundary_features=(),
        )
        overlap = rules.seen_share(self.areas[best], after)
        return self._enter(candidate, seq, best, overlap, Rule.RECOGNISED)

    def _recognisable(self) -> bool:
        """Whether a known area other than the current one has frames (has a profile)."""
        current, areas, merged = self.current, self.areas, self.merged
        for area, frames in enumerate(self.area_frames):
            # ``_live``'s areas with frames: not merged, not forgotten (their counts kept)
            if frames > 0 and area != current and areas[area] and area not in merged:
                return True
        return False

    def _blind(self, boundary: int) -> bool:
        """Whether the robot reached the new side blind (rule 3b)."""
        p = self.params
        if rules.blind_before(self.frames, boundary, p.blind_frames):
            return True
        if rules.blind_gap(
            self.frames, self.gaps, boundary, (p.blind_frames, p.blind_span), p.blind_margin
        ):
            return True
        return bool(p.blind_span) and (
            rules.blind_run(self.frames, boundary, p.blind_margin) >= p.blind_span
        )

    def _profile(self, area: int) -> Profile | None:
        if area not in self._profiles:
            self._profiles[area] = profile(self.areas[area], self.area_frames[area])
        return self._profiles[area]

    # -- rules 6, 7: the area model --------------------------------------------------------

    def _live(self) -> Iterable[int]:
        """The areas a robot can enter again: neither merged nor forgotten (rule 9)."""
        return (
            area
            for area in range(len(self.areas))
            if area not in self.merged and (self.areas[area] or not self.area_frames[area])
        )

    def _bound_models(self) -> None:
        """Forget the smallest areas' features while the models hold too many (rule 9)."""
        bound = self.params.max_area_sightings
        if not bound or self.sightings <= bound:
            return
        keep = bound - bound // 4
        order = sorted(
            (self.area_frames[area], area)
            for area in range(len(self.areas))
            if area != self.current and self.areas[area]
        )
        for _, area in order:
            if self.sightings <= keep:
                break
            self.sightings -= len(self.areas[area])
            self.areas[area] = {}
            self._profiles.pop(area, None)

    def _count_sightings(self) -> None:
        self.sightings = sum(map(len, self.areas))

    def _merges_with(self, known: int, after: dict[int, int], moved: int) -> bool:
        """Merge ``known`` and the current area if they overlap enough (rule 6).

        The current area is compared as it would be left: without the frames from the
        boundary on (``after``, ``moved`` of them non-empty), which would go to ``known``.
        """
        current = self.current
        left = without(self.areas[current], after)
        overlap = rate_overlap(
            left, self.area_frames[current] - moved, self.areas[known], self.area_frames[known]
        )
        if overlap < self.params.merge_overlap:
            return False
        keep = merge(self.areas, self.area_frames, self.merged, current, known)
        self._count_sightings()
        self.current = keep
        self._profiles.pop(current, None)
        self._profiles.pop(known, None)
        return True

    def _enter(
        self,
        candidate: Candidate,
        seq: int,
        known: int | None,
        overlap: float,
        rule: Rule,
    ) -> AreaTransition:
        """Close the segment at the boundary, move its new frames to the area entered."""
        boundary = candidate.boundary_seq
        after, _, moved_nonempty = rules.sides(self.frames, self.segment_counts, boundary)
        left = self.current
        if known is None:
            self.areas.append({})
            self.area_frames.append(0)
            area = len(self.areas) - 1
        else:
            area = known
        move(self.areas, self.area_frames, left, area, after, moved_nonempty)
        self._count_sightings()
        self._profiles.pop(left, None)
        self._profiles.pop(area, None)
        # the segments (submaps) meet at the seam, at or after the area boundary
        p = self.params
        seam = rules.seam(
            self.frames, self.segment_counts, boundary, p.seam_frames, p.min_area_features
        )
        if seam != boundary:
            candidate = replace(candidate, boundary_seq=seam)
            after, before, _ = rules.sides(self.frames, self.segment_counts, seam)
        else:
            before = without(self.segment_counts, after)
        moved = [frame for frame in self.frames if frame[0] >= seam]
        first = self.segment_first_seq if self.segment_first_seq is not None else seq
        transition = segment_transition(
            candidate,
            seq,
            self.last_stamp_s,
            closed=(self.segment_id, first, self.segment_frame_count - len(moved), before),
            opened=(len(moved), after),
        )
        self.frames.clear()
        self.frames.extend(moved)
        self._forget_gaps()
        self.segment_id += 1
        self.segment_first_seq = seam
        self.segment_frame_count = len(moved)
        self.segment_counts = dict(after)
        self.current = area
        self.candidate = None
        self.transitions += 1
        return AreaTransition(
            transition=transition,
            area=area,
            left_area=left,
            revisit_of=known,
            overlap=overlap,
            rule=rule,
        )

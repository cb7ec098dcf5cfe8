"""Areas on top of LESS-mapping: pooled evidence, confirmed splits, recognised revisits.

The paper's partitioner (``lessmap.core.partitioner``) declares a transition whenever its
CovGraph passes Eq. 4 or falls apart. On sparse landmark streams that makes fragments of one
or two features; with a 360° sensor it answers late, because the room left behind stays in
view through the door; and every return to a room opens an anonymous new submap.
``AreaTracker`` drives one ``Partitioner`` as a *proposer* of new areas, keeps a model of
every area it confirmed, and recognises a known area when the robot comes back to it.

Rules of this file (the comment at each ``AreaParams`` field says why its default is what
it is, measured with ``python -m lessmap.evaluation.areabench``):

1. **Minimum evidence.** Frames are pooled before they reach the proposer: a pool closes
   when it holds ``pool_min_features`` distinct features or spans ``pool_max_frames``
   frames, and enters the proposer as one frame.
2. **Proposals.** The proposer runs the paper's test (Eq. 4 or a disconnected graph) with
   its own thresholds (``proposal``; looser than the paper's so it answers sooner). A
   proposal names a boundary frame: the first frame of the pool where the proposer's new
   side starts. A later proposal replaces a pending one.
3. **Confirmation.** A proposal becomes a transition when all of these hold:

   a. the frames of the current segment before the boundary hold ``min_area_features``
      distinct features (else the proposal is dropped: no closed area is that small), and
      the frames from the boundary on hold as many within ``confirm_frames`` frames of the
      proposal (else it expires);
   b. the boundary does not follow ``blind_frames`` empty frames: a robot that saw nothing
      saw no boundary (a room wider than the sensor's range, crossed blind);
   c. the frames from the boundary on are not the current area's own: when ``stay_share``
      of their sightings are of features *familiar* to the current area (seen in
      ``familiar_rate`` of its non-empty frames, leaving out the frames from the boundary
      on and the ``familiar_margin_frames`` non-empty frames before it, where a doorway
      shows the next room), the robot moved within its area and the proposal is dropped.

4. **Which area, on a proposal.** The features seen from the boundary on are compared with
   every known area other than the current one: the share of them that the area has seen.
   The best area with a share of at least ``revisit_overlap`` is entered again
   (``revisit_of``); otherwise a new area is opened.
5. **Recognition.** An area's *profile* gives each feature the probability
   ``(count + 1/2) / (frames + 1)`` of a sighting in one of its frames, features
   independent. When each of the last ``recognise_frames`` non-empty frames is more likely
   under a known area's profile than under the current area's (fitted without those
   frames), by ``recognise_llr`` nats per frame on average, the robot is back in that
   area: the change needs no proposal. Its boundary walks back over the earlier frames
   that also fit the known area better. Rules 3a (without waiting), 3b and 6 apply.
6. **Merging.** When a change (rule 4 or 5) would enter a known area whose *rate overlap*
   with the current area as it would be left (without the frames from the boundary on),
   ``Σ_f min(r_A(f), r_B(f)) / min(Σ_f r_A(f), Σ_f r_B(f))`` with ``r_X(f)`` the share of
   X's non-empty frames that saw f, is at least ``merge_overlap``, the two are one area seen
   in two parts: they merge (the later id into the earlier), the frames stay where they
   are, and no transition is reported.
7. **Area model.** Each area keeps, per feature, the number of its frames that saw it, and
   its number of non-empty frames. On a transition the frames from the boundary on move
   from the area left to the area entered. Area ids count from 0 per tracker, in order of
   opening; a merged id is never reused.
8. **State.** Everything that influences a later decision is in ``AreaTracker``'s fields and
   round-trips through ``lessmap.core.areas_snapshot`` bit for bit; the proposer is a
   ``Partitioner``, so its state is the paper's snapshot. Cached profiles are derived from
   those fields, summed in their (preserved) order, so a restored tracker gets equal floats.

No I/O, no clock, no logging: frames in, ``AreaTransition`` out.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING

from lessmap.core.errors import GraphError, StaleFrameError
from lessmap.core.params import PartitionParams
from lessmap.core.partitioner import Partitioner
from lessmap.core.submaps import Reason, Submap, Transition

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

Frame = tuple[int, tuple[int, ...]]  # (seq, distinct feature IDs ascending)


def _default_proposal() -> PartitionParams:
    # Looser than the paper's (0.25, 0.2), so a first visit is found within a few frames of
    # the door; rules 3c and 6 drop what it proposes inside an area. Ncut 0.35: 360° sparse
    # R / P 90.3 / 92.1%; 0.45: 270° dense R 95.3%, 270° sparse 94.0% (defaults: 94.3 / 96.2,
    # 98.0, 98.8). λ2 never binds here: (0.45, 0.4) decides as (0.45, 0.45).
    return PartitionParams(ncut_min=0.4, lambda2_min=0.4)


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaParams:
    """How an ``AreaTracker`` pools, confirms, recognises and names areas (module doc).

    Figures in the comments come from ``python -m lessmap.evaluation.areabench --seeds 5``
    with the one field changed from the defaults (the defaults' figure in parentheses);
    R / P are recall / precision within ±8 frames, "per 10 min" counts transitions per robot
    per 10 minutes, "open rooms" are the simulated rooms with no doors.
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
    # Rule 3b. No simulated building has an empty frame before a door, so one is enough; 0
    # (off): 12-16 m open rooms, where a 5 m sensor sees nothing mid-room, 18.10 / 16.82 /
    # 3.36 per 10 min at 270° dense / 360° dense / 270° sparse (3.04 / 1.84 / 0.56).
    blind_frames: int = 1
    # Rule 3c. Above 1 (off): 8-10 m open rooms 7.93 per 10 min (1.12), 360° sparse revisits
    # 90.0% recognised (100), dlr 131 transitions (102); 0.4: 270° dense R 95.5% and 3.6%
    # false area names (98.0, 1.0%); 0.6: 12-16 m open rooms 4.48 per 10 min (3.04).
    stay_share: float = 0.5
    # 0.2: open rooms 2.00 / 1.28 / 1.60 per 10 min at 8-10 m (1.12 / 0.72 / 0.72).
    familiar_rate: float = 0.1
    # A short first stay would keep the next room, seen through the door, as familiar: 0
    # frames gives 270° sparse R 96.0% and 2.4% false names (98.8, 0.0%); 8 frames gives
    # 12-16 m open rooms at 270° 4.00 per 10 min (3.04) and dlr 113 transitions (102).
    familiar_margin_frames: int = 3
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

    def __post_init__(self) -> None:
        checks = {
            "pool_min_features": self.pool_min_features >= 1,
            "pool_max_frames": self.pool_max_frames >= 1,
            "min_area_features": self.min_area_features >= 1,
            "revisit_overlap": 0.0 < self.revisit_overlap <= 1.0,
            "confirm_frames": self.confirm_frames >= 0,
            "history_frames": self.history_frames >= 1,
            "blind_frames": self.blind_frames >= 0,
            "stay_share": self.stay_share > 0.0,
            "familiar_rate": 0.0 < self.familiar_rate <= 1.0,
            "familiar_margin_frames": self.familiar_margin_frames >= 0,
            "recognise_frames": self.recognise_frames >= 0,
            "recognise_llr": self.recognise_llr >= 0.0,
            "merge_overlap": self.merge_overlap > 0.0,
        }
        for name, ok in checks.items():
            if not ok:
                msg = f"invalid area parameter {name}={getattr(self, name)!r}"
                raise GraphError(msg)


class Rule(StrEnum):
    """Which rule found an area change."""

    SPLIT = "split"  # a proposal of the paper's test, confirmed (rules 2-4)
    RECOGNISED = "recognised"  # the last frames fit a known area better (rule 5)


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaTransition:
    """The robot left one area for another; ``transition`` in the paper's terms.

    ``transition.closed`` and ``transition.opened`` are the segments of frames on either
    side of the boundary (their ids count segments, from 0 per tracker); ``area`` and
    ``left_area`` name the areas those segments belong to. A ``RECOGNISED`` change ran no
    Eq. 4 test: its ``transition.reason`` is ``SPECTRAL`` with ``ncut`` and ``lambda2``
    None, and ``rule`` says so.
    """

    transition: Transition
    area: int  # the area entered
    left_area: int  # the area left
    revisit_of: int | None  # == area when the area was known before, else None
    overlap: float  # share of the new frames' features the entered area had seen (0: new)
    rule: Rule = Rule.SPLIT


@dataclass(frozen=True, slots=True, kw_only=True)
class Candidate:
    """A proposal waiting for confirmation (rule 3)."""

    boundary_seq: int  # first frame of the proposed new side
    seq: int  # frame at which the proposal was made
    reason: Reason
    ncut: float | None
    lambda2: float | None
    boundary_features: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class Profile:
    """An area's sightings as a likelihood of frames (rule 5)."""

    absent: float  # log-likelihood of a frame that sees none of the area's features
    gain: dict[int, float]  # what seeing a feature the area knows adds: log p - log(1 - p)
    unseen: float  # log p of a feature the area never saw

    def loglik(self, features: Iterable[int]) -> float:
        """Log-likelihood of one frame's distinct features."""
        total = self.absent
        for feature in features:
            total += self.gain.get(feature, self.unseen)
        return total


def profile(
    counts: dict[int, int], frames: int, leave: dict[int, int] | None = None, left: int = 0
) -> Profile | None:
    """Return the profile of ``counts`` over ``frames`` non-empty frames.

    ``left`` of those frames, which saw ``leave``, are taken out first; None when no frame
    remains.
    """
    remaining = frames - left
    if remaining <= 0:
        return None
    # (count + 1/2) / (frames + 1): never 0 or 1, so one odd frame is never impossible.
    denominator = remaining + 1.0
    absent = 0.0
    gain: dict[int, float] = {}
    for feature, count in counts.items():
        seen = count - leave.get(feature, 0) if leave else count
        if seen <= 0:
            continue
        p = (seen + 0.5) / denominator
        absent += math.log1p(-p)
        gain[feature] = math.log(p) - math.log1p(-p)
    return Profile(absent, gain, math.log(0.5 / denominator))


def rate_overlap(a: dict[int, int], frames_a: int, b: dict[int, int], frames_b: int) -> float:
    """Rule 6's overlap of two areas' sighting rates (0: disjoint, 1: one within the other)."""
    if frames_a <= 0 or frames_b <= 0 or not a or not b:
        return 0.0
    shared = sum(min(n / frames_b, a.get(feature, 0) / frames_a) for feature, n in b.items())
    return shared / min(sum(a.values()) / frames_a, sum(b.values()) / frames_b)


def _distinct(seq: int, features: Iterable[int]) -> tuple[int, ...]:
    """Return the distinct feature IDs in ascending order, refusing non-integers."""
    values = list(features)
    for value in values:
        # bool is an int subclass; numpy integers pass through __index__
        if isinstance(value, bool) or not hasattr(value, "__index__"):
            msg = f"frame {seq}: feature IDs must be integers, got {value!r}"
            raise GraphError(msg)
    return tuple(sorted({int(value) for value in values}))


def _count(into: dict[int, int], features: Iterable[int]) -> None:
    for feature in features:
        into[feature] = into.get(feature, 0) + 1


def _tally(frames: Iterable[Frame]) -> tuple[dict[int, int], int]:
    """Sightings per feature, and the number of non-empty frames."""
    counts: dict[int, int] = {}
    nonempty = 0
    for _, features in frames:
        _count(counts, features)
        nonempty += bool(features)
    return counts, nonempty


class AreaTracker:
    """Areas of one robot session from its frames. No I/O."""

    def __init__(self, params: AreaParams | None = None) -> None:
        """Start an empty session in area 0."""
        self.params = params if params is not None else AreaParams()
        self.proposer = Partitioner(self.params.proposal)
        # pooling (rule 1)
        self.pool: set[int] = set()
        self.pool_first_seq: int | None = None
        self.pool_frames = 0
        self.pool_index = 0
        self.pool_starts: deque[tuple[int, int]] = deque(
            maxlen=self.params.proposal.history_frames + 1
        )  # (pool index, its first frame seq)
        # the current segment (frames since the last transition)
        self.segment_id = 0
        self.segment_first_seq: int | None = None
        self.segment_frame_count = 0
        self.segment_counts: dict[int, int] = {}  # feature -> frames of the segment
        self.frames: deque[Frame] = deque(maxlen=self.params.history_frames)
        # areas (rule 7); a merged area keeps its slot, empty, and its entry in ``merged``
        self.areas: list[dict[int, int]] = [{}]
        self.area_frames: list[int] = [0]  # non-empty frames per area
        self.merged: dict[int, int] = {}  # merged area -> the area it merged into
        self.current = 0
        self.candidate: Candidate | None = None
        self.last_seq: int | None = None
        self.last_stamp_s = 0.0
        self.frames_applied = 0
        self.transitions = 0
        self._profiles: dict[int, Profile | None] = {}  # derived from areas (rule 8)

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
        """Add one frame; return the area change it confirms, if any.

        Raises:
            StaleFrameError: seq is not greater than the last seq.
            GraphError: a feature ID is not an integer.
        """
        if self.last_seq is not None and seq <= self.last_seq:
            msg = f"frame seq {seq} is not after the last applied seq {self.last_seq}"
            raise StaleFrameError(msg)
        distinct = _distinct(seq, features)
        self.last_seq = seq
        self.last_stamp_s = float(stamp_s)
        self.frames_applied += 1
        if self.segment_first_seq is None:
            self.segment_first_seq = seq
        self.segment_frame_count += 1
        self.frames.append((seq, distinct))
        _count(self.segment_counts, distinct)
        if distinct:
            _count(self.areas[self.current], distinct)
            self.area_frames[self.current] += 1
            self._profiles.pop(self.current, None)
        self._pool(seq, distinct)
        if self.candidate is not None:
            change = self._confirm(seq)
            if change is not None:
                return change
        if distinct and self.params.recognise_frames:
            return self._recognise(seq)
        return None

    def _pool(self, seq: int, distinct: tuple[int, ...]) -> None:
        """Add a frame to the pool; hand a full pool to the proposer (rules 1, 2)."""
        if self.pool_first_seq is None:
            self.pool_first_seq = seq
        self.pool.update(distinct)
        self.pool_frames += 1
        full = len(self.pool) >= self.params.pool_min_features
        if not full and self.pool_frames < self.params.pool_max_frames:
            return
        index = self.pool_index
        self.pool_starts.append((index, self.pool_first_seq))
        proposal = self.proposer.observe(index, self.last_stamp_s, sorted(self.pool))
        self.pool_index += 1
        self.pool.clear()
        self.pool_first_seq = None
        self.pool_frames = 0
        if proposal is not None:
            starts = dict(self.pool_starts)
            self.candidate = Candidate(
                boundary_seq=starts.get(proposal.boundary_seq, seq),
                seq=seq,
                reason=proposal.reason,
                ncut=proposal.ncut,
                lambda2=proposal.lambda2,
                boundary_features=proposal.boundary_features,
            )

    # -- rules 3, 4: a proposal ------------------------------------------------------------

    def _confirm(self, seq: int) -> AreaTransition | None:
        """Confirm, keep waiting on, or drop the pending proposal (rules 3, 4, 6)."""
        candidate = self.candidate
        assert candidate is not None
        boundary = candidate.boundary_seq
        after, before, moved = self._sides(boundary)
        minimum = self.params.min_area_features
        if len(before) < minimum:
            self.candidate = None  # no closed area is this small: the segment goes on
            return None
        if len(after) < minimum:
            if seq - candidate.seq >= self.params.confirm_frames:
                self.candidate = None
            return None
        if self._blind_before(boundary) or self._familiar_share(boundary, after) >= (
            self.params.stay_share
        ):
            self.candidate = None
            return None
        known, overlap = self._known_area(after)
        if known is not None and self._merges_with(known, after, moved):
            self.candidate = None
            return None
        return self._enter(candidate, seq, known, overlap, Rule.SPLIT)

    def _sides(self, boundary: int) -> tuple[dict[int, int], dict[int, int], int]:
        """Split the segment at the boundary.

        Returns:
            Sightings per feature from the boundary on, the features seen before it, and
            the number of non-empty frames from the boundary on.
        """
        after, moved = _tally(frame for frame in self.frames if frame[0] >= boundary)
        before = {
            feature: n - after.get(feature, 0)
            for feature, n in self.segment_counts.items()
            if n > after.get(feature, 0)
        }
        return after, before, moved

    def _blind_before(self, boundary: int) -> bool:
        """Whether the first sighting from the boundary on follows ``blind_frames`` empty frames.

        Rule 3b. A pool may start on an empty frame, so the empty frames right after the
        boundary count too.
        """
        if not self.params.blind_frames:
            return False
        empty = 0
        for frame_seq, features in self.frames:
            if features:
                if frame_seq >= boundary:
                    break
                empty = 0
            else:
                empty += 1
        return empty >= self.params.blind_frames

    def _familiar_share(self, boundary: int, after: dict[int, int]) -> float:
        """Share of the new frames' sightings the current area knows well (rule 3c)."""
        margin = self.params.familiar_margin_frames
        start = boundary
        if margin:
            earlier = [s for s, features in self.frames if features and s < boundary]
            if earlier:
                start = earlier[-min(margin, len(earlier))]
        left_out, left_frames = _tally(frame for frame in self.frames if frame[0] >= start)
        frames = self.area_frames[self.current] - left_frames
        if frames <= 0:
            return 0.0
        counts = self.areas[self.current]
        least = self.params.familiar_rate * frames
        familiar = 0
        for feature, n in after.items():
            seen = counts.get(feature, 0) - left_out.get(feature, 0)
            if seen > 0 and seen >= least:
                familiar += n
        return familiar / sum(after.values())

    def _known_area(self, after: dict[int, int]) -> tuple[int | None, float]:
        """The known area (not the current one) that has seen most of ``after`` (rule 4)."""
        best: int | None = None
        share = 0.0
        for area in self._live():
            counts = self.areas[area]
            if area == self.current or not counts:
                continue
            seen = sum(1 for feature in after if feature in counts) / len(after)
            if seen > share:
                best, share = area, seen
        if best is None or share < self.params.revisit_overlap:
            return None, 0.0
        return best, share

    # -- rule 5: recognition ---------------------------------------------------------------

    def _recognise(self, seq: int) -> AreaTransition | None:
        """Enter the known area the last frames fit better than the current one, if any."""
        first = self.segment_first_seq
        window = self._last_nonempty(self.params.recognise_frames)
        if first is None or window is None or window[0][0] <= first:
            return None
        leave, left = _tally(window)
        here = profile(self.areas[self.current], self.area_frames[self.current], leave, left)
        if here is None:
            return None
        fits_here = [here.loglik(features) for _, features in window]
        best: int | None = None
        best_gain = 0.0
        for area in self._live():
            there = self._profile(area) if area != self.current else None
            if there is None:
                continue
            gains = [there.loglik(f) - h for (_, f), h in zip(window, fits_here, strict=True)]
            gain = sum(gains) / len(gains)
            if min(gains) > 0 and gain >= self.params.recognise_llr and gain > best_gain:
                best, best_gain = area, gain
        if best is None:
            return None
        there = self._profile(best)
        assert there is not None
        boundary = window[0][0]
        for frame_seq, features in reversed(self.frames):
            if frame_seq >= boundary:
                continue
            if frame_seq <= first:
                break
            if not features:
                continue
            if there.loglik(features) <= here.loglik(features):
                break
            boundary = frame_seq
        after, before, moved = self._sides(boundary)
        minimum = self.params.min_area_features
        if len(before) < minimum or len(after) < minimum or self._blind_before(boundary):
            return None
        if self._merges_with(best, after, moved):
            return None
        counts = self.areas[best]
        overlap = sum(1 for feature in after if feature in counts) / len(after)
        candidate = Candidate(
            boundary_seq=boundary,
            seq=seq,
            reason=Reason.SPECTRAL,
            ncut=None,
            lambda2=None,
            boundary_features=(),
        )
        return self._enter(candidate, seq, best, overlap, Rule.RECOGNISED)

    def _last_nonempty(self, count: int) -> Sequence[Frame] | None:
        """The last ``count`` non-empty frames, oldest first (None if fewer)."""
        found: list[Frame] = []
        for frame in reversed(self.frames):
            if frame[1]:
                found.append(frame)
                if len(found) == count:
                    return found[::-1]
        return None

    def _profile(self, area: int) -> Profile | None:
        if area not in self._profiles:
            self._profiles[area] = profile(self.areas[area], self.area_frames[area])
        return self._profiles[area]

    # -- rules 6, 7: the area model --------------------------------------------------------

    def _live(self) -> Iterable[int]:
        return (area for area in range(len(self.areas)) if area not in self.merged)

    def _merges_with(self, known: int, after: dict[int, int], moved: int) -> bool:
        """Merge ``known`` and the current area if they overlap enough (rule 6).

        The current area is compared as it would be left: without the frames from the
        boundary on (``after``, ``moved`` of them non-empty), which would go to ``known``.
        """
        current = self.current
        left = {
            feature: n - after.get(feature, 0)
            for feature, n in self.areas[current].items()
            if n > after.get(feature, 0)
        }
        overlap = rate_overlap(
            left, self.area_frames[current] - moved, self.areas[known], self.area_frames[known]
        )
        if overlap < self.params.merge_overlap:
            return False
        keep, gone = min(current, known), max(current, known)
        into = self.areas[keep]
        for feature, n in self.areas[gone].items():
            into[feature] = into.get(feature, 0) + n
        self.areas[gone] = {}
        self.area_frames[keep] += self.area_frames[gone]
        self.area_frames[gone] = 0
        self.merged[gone] = keep
        self.current = keep
        self._profiles.pop(keep, None)
        self._profiles.pop(gone, None)
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
        after, before, moved_nonempty = self._sides(boundary)
        moved = [frame for frame in self.frames if frame[0] >= boundary]
        left = self.current
        if known is None:
            self.areas.append({})
            self.area_frames.append(0)
            area = len(self.areas) - 1
        else:
            area = known
        left_counts, area_counts = self.areas[left], self.areas[area]
        for feature, n in after.items():
            remaining = left_counts.get(feature, 0) - n
            if remaining > 0:
                left_counts[feature] = remaining
            else:
                left_counts.pop(feature, None)
            area_counts[feature] = area_counts.get(feature, 0) + n
        self.area_frames[left] -= moved_nonempty
        self.area_frames[area] += moved_nonempty
        self._profiles.pop(left, None)
        self._profiles.pop(area, None)
        first = self.segment_first_seq if self.segment_first_seq is not None else seq
        closed = Submap(
            id=self.segment_id,
            first_seq=first,
            last_seq=max(first, boundary - 1),
            frame_count=self.segment_frame_count - len(moved),
            features=tuple(sorted(before)),
        )
        opened = Submap(
            id=self.segment_id + 1,
            first_seq=boundary,
            last_seq=seq,
            frame_count=len(moved),
            features=tuple(sorted(after)),
        )
        transition = Transition(
            seq=seq,
            boundary_seq=boundary,
            stamp_s=self.last_stamp_s,
            reason=candidate.reason,
            ncut=candidate.ncut,
            lambda2=candidate.lambda2,
            closed=closed,
            opened=opened,
            boundary_features=candidate.boundary_features,
            batch_frames=1,
        )
        self.frames.clear()
        self.frames.extend(moved)
        self.segment_id += 1
        self.segment_first_seq = boundary
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

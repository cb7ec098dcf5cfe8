"""Areas on top of LESS-mapping: pooled evidence, confirmed splits, named revisits.

The paper's partitioner (``lessmap.core.partitioner``) declares a transition whenever its
CovGraph passes Eq. 4 or falls apart. On sparse landmark streams that makes fragments of one
or two features, and every return to a room opens an anonymous new submap. ``AreaTracker``
drives one ``Partitioner`` as a *proposer* and turns its proposals into area changes.

Rules of this file:

1. **Minimum evidence.** Frames are pooled before they reach the proposer: a pool closes
   when it holds ``pool_min_features`` distinct features or spans ``pool_max_frames``
   frames, and enters the proposer as one frame. A dense sensor (a frame of ten features
   or more) pools nothing; a sensor that sees one or two landmarks per frame is tested on
   a few frames at once.
2. **Proposals.** The proposer runs the paper's test (Eq. 4 or a disconnected graph) with
   its own thresholds (``proposal``; looser than the paper's so it answers sooner). A
   proposal names a boundary frame: the first frame of the pool where the proposer's new
   side starts. A later proposal replaces a pending one.
3. **Confirmation.** A proposal becomes a transition when the frames of the current segment
   before the boundary hold at least ``min_area_features`` distinct features (else it is
   dropped: no closed area is ever that small) and the frames from the boundary on hold as
   many too, within ``confirm_frames`` frames of the proposal (else it expires).
4. **Which area.** The features seen from the boundary on are compared with every known
   area other than the current one: the share of them that the area has seen. The best
   area with a share of at least ``revisit_overlap`` is entered again (``revisit_of``);
   otherwise a new area is opened. Area ids count from 0 per tracker, in order of opening.
5. **Area model.** Each area keeps, per feature, the number of its frames that saw it. On a
   transition the frames from the boundary on move from the area left to the area entered.
6. **State.** Everything that influences a later decision is in ``AreaTracker``'s fields and
   round-trips through ``lessmap.core.areas_snapshot`` bit for bit; the proposer is a
   ``Partitioner``, so its state is the paper's snapshot.

No I/O, no clock, no logging: frames in, ``AreaTransition`` out.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lessmap.core.errors import GraphError, StaleFrameError
from lessmap.core.params import PartitionParams
from lessmap.core.partitioner import Partitioner
from lessmap.core.submaps import Reason, Submap, Transition

if TYPE_CHECKING:
    from collections.abc import Iterable


def _default_proposal() -> PartitionParams:
    # Looser than the paper's (0.25, 0.2): the proposer answers within a frame or two of a
    # door; rules 3 and 4 drop what it proposes inside an area. Measured in
    # lessmap.evaluation.areabench.
    return PartitionParams(ncut_min=0.4, lambda2_min=0.4)


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaParams:
    """How an ``AreaTracker`` pools, confirms and names areas (rules in the module doc)."""

    proposal: PartitionParams = field(default_factory=_default_proposal)
    pool_min_features: int = 6  # a pool closes with this many distinct features ...
    pool_max_frames: int = 4  # ... or after this many frames
    min_area_features: int = 5  # fewest distinct features on either side of a transition
    revisit_overlap: float = 0.5  # share of the new frames' features a known area must hold
    confirm_frames: int = 12  # a proposal not confirmed within this many frames expires
    history_frames: int = 4000  # frames of the current segment kept (oldest go first)

    def __post_init__(self) -> None:
        checks = {
            "pool_min_features": self.pool_min_features >= 1,
            "pool_max_frames": self.pool_max_frames >= 1,
            "min_area_features": self.min_area_features >= 1,
            "revisit_overlap": 0.0 < self.revisit_overlap <= 1.0,
            "confirm_frames": self.confirm_frames >= 0,
            "history_frames": self.history_frames >= 1,
        }
        for name, ok in checks.items():
            if not ok:
                msg = f"invalid area parameter {name}={getattr(self, name)!r}"
                raise GraphError(msg)


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaTransition:
    """The robot left one area for another; ``transition`` in the paper's terms.

    ``transition.closed`` and ``transition.opened`` are the segments of frames on either
    side of the boundary (their ids count segments, from 0 per tracker); ``area`` and
    ``left_area`` name the areas those segments belong to.
    """

    transition: Transition
    area: int  # the area entered
    left_area: int  # the area left
    revisit_of: int | None  # == area when the area was known before, else None
    overlap: float  # share of the new frames' features the entered area had seen (0: new)


@dataclass(frozen=True, slots=True, kw_only=True)
class Candidate:
    """A proposal waiting for confirmation (rule 3)."""

    boundary_seq: int  # first frame of the proposed new side
    seq: int  # frame at which the proposal was made
    reason: Reason
    ncut: float | None
    lambda2: float | None
    boundary_features: tuple[int, ...]


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
        self.frames: deque[tuple[int, tuple[int, ...]]] = deque(maxlen=self.params.history_frames)
        # areas (rule 5)
        self.areas: list[dict[int, int]] = [{}]
        self.current = 0
        self.candidate: Candidate | None = None
        self.last_seq: int | None = None
        self.last_stamp_s = 0.0
        self.frames_applied = 0
        self.transitions = 0

    # -- read ------------------------------------------------------------------------------

    @property
    def area_count(self) -> int:
        """Areas opened so far (the current one included)."""
        return len(self.areas)

    def area_features(self, area: int) -> tuple[int, ...]:
        """The features an area's frames have seen, ascending."""
        return tuple(sorted(self.areas[area]))

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
        _count(self.areas[self.current], distinct)
        self._pool(seq, distinct)
        if self.candidate is None:
            return None
        return self._confirm(seq)

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

    def _confirm(self, seq: int) -> AreaTransition | None:
        """Confirm, keep waiting on, or drop the pending proposal (rules 3, 4)."""
        candidate = self.candidate
        assert candidate is not None
        after: dict[int, int] = {}
        after_frames = 0
        for frame_seq, frame in self.frames:
            if frame_seq >= candidate.boundary_seq:
                _count(after, frame)
                after_frames += 1
        before = {
            feature: n - after.get(feature, 0)
            for feature, n in self.segment_counts.items()
            if n > after.get(feature, 0)
        }
        minimum = self.params.min_area_features
        if len(before) < minimum:
            self.candidate = None  # no closed area is this small: the segment goes on
            return None
        if len(after) < minimum:
            if seq - candidate.seq >= self.params.confirm_frames:
                self.candidate = None
            return None
        best, overlap = self._known_area(after)
        return self._enter(candidate, seq, before, after, after_frames, best, overlap)

    def _known_area(self, after: dict[int, int]) -> tuple[int | None, float]:
        """The known area (not the current one) that has seen most of ``after`` (rule 4)."""
        best: int | None = None
        share = 0.0
        for area, counts in enumerate(self.areas):
            if area == self.current or not counts:
                continue
            seen = sum(1 for feature in after if feature in counts) / len(after)
            if seen > share:
                best, share = area, seen
        if best is None or share < self.params.revisit_overlap:
            return None, 0.0
        return best, share

    def _enter(
        self,
        candidate: Candidate,
        seq: int,
        before: dict[int, int],
        after: dict[int, int],
        after_frames: int,
        known: int | None,
        overlap: float,
    ) -> AreaTransition:
        """Close the segment at the boundary, move its new frames to the area entered."""
        left = self.current
        if known is None:
            self.areas.append({})
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
        first = self.segment_first_seq if self.segment_first_seq is not None else seq
        boundary = candidate.boundary_seq
        closed = Submap(
            id=self.segment_id,
            first_seq=first,
            last_seq=max(first, boundary - 1),
            frame_count=self.segment_frame_count - after_frames,
            features=tuple(sorted(before)),
        )
        opened = Submap(
            id=self.segment_id + 1,
            first_seq=boundary,
            last_seq=seq,
            frame_count=after_frames,
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
        kept = [(s, f) for s, f in self.frames if s >= boundary]
        self.frames.clear()
        self.frames.extend(kept)
        self.segment_id += 1
        self.segment_first_seq = boundary
        self.segment_frame_count = after_frames
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
        )

"""Rooms of one robot session: a windowed cut of the frames, confirmed, its areas named.

The paper cuts everything seen since the last change, so a small room must outweigh the
area before it. Here the cut is local (``docs/design/rooms.md`` has the reasons):

1. Window: non-empty frames; a half spans the frames over which the view keeps
   ``window_similarity`` of its CovRate from one place, learnt from the lag profile.
2. Cut: within-half minus across-half similarity, less what a steady walk gives; a peak of
   at least ``cut_min`` proposes a change at the newer half's first frame.
3. Confirmation: each side holds ``min_side_features``; the newer half is not what the
   area knew before the window (``known_share``), unless the cut is ``sure_cut``.
4. Naming: the other area holding ``revisit_overlap`` of the newer half is entered again.
5. Models: per-feature sightings of the segment and of each area, bounded by
   ``max_area_sightings``; every field round-trips through ``lessmap.core.rooms.snapshot``.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

from lessmap.core.areas.events import AreaTransition, Candidate, Rule
from lessmap.core.areas.profile import count, distinct
from lessmap.core.errors import StaleFrameError
from lessmap.core.paper.submaps import Reason, Submap
from lessmap.core.rooms.params import RoomParams
from lessmap.core.rooms.window import Cut, FrameWindow

if TYPE_CHECKING:
    from collections.abc import Iterable

from lessmap.core.areas.events import segment_transition

#: Frames (empty ones too) whose seqs are kept to count a new segment's frames.
SEQ_MEMORY = 4096


class RoomTracker:
    """Rooms of one robot session. No I/O."""

    def __init__(self, params: RoomParams | None = None) -> None:
        """Start an empty session in area 0."""
        self.params = params if params is not None else RoomParams()
        self.window = FrameWindow(self.params)
        self.cuts: deque[Cut] = deque(maxlen=2 * self.params.window_max_frames + 1)
        self.seqs: deque[int] = deque(maxlen=SEQ_MEMORY)  # every applied frame's seq
        self.segment_id = 0
        self.segment_first_seq: int | None = None
        self.segment_frame_count = 0
        self.segment_counts: dict[int, int] = {}
        self.segment_nonempty = 0
        self.areas: list[dict[int, int]] = [{}]
        self.area_frames: list[int] = [0]
        self.current = 0
        self.last_boundary: int | None = None
        self.last_seq: int | None = None
        self.last_stamp_s = 0.0
        self.frames_applied = 0
        self.transitions = 0

    # -- read ------------------------------------------------------------------------------

    @property
    def sightings(self) -> int:
        """(feature, area) entries the area models hold (rule 5)."""
        return sum(len(area) for area in self.areas)

    @property
    def area_count(self) -> int:
        """Areas opened so far."""
        return len(self.areas)

    def area_of(self, area: int) -> int:
        """The area an id stands for (areas never merge here)."""
        return area

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

    def feature_known(self, feature: int) -> bool:
        """Whether the current segment or window has seen a feature."""
        return feature in self.segment_counts

    # -- frames ----------------------------------------------------------------------------

    def observe(self, seq: int, stamp_s: float, features: Iterable[int]) -> AreaTransition | None:
        """Add one frame, cut the window and test the cut; return the change it confirms.

        Raises:
            StaleFrameError: seq is not greater than the last seq.
            GraphError: a feature ID is not an integer.
        """
        if self.last_seq is not None and seq <= self.last_seq:
            msg = f"frame seq {seq} is not after the last applied seq {self.last_seq}"
            raise StaleFrameError(msg)
        seen = distinct(seq, features)
        self.last_seq = seq
        self.last_stamp_s = float(stamp_s)
        self.frames_applied += 1
        self.seqs.append(seq)
        if self.segment_first_seq is None:
            self.segment_first_seq = seq
        self.segment_frame_count += 1
        if not seen:
            return None  # a robot that saw nothing saw no boundary
        count(self.segment_counts, seen)
        self.segment_nonempty += 1
        count(self.areas[self.current], seen)
        self.area_frames[self.current] += 1
        self.window.add(seq, frozenset(seen))
        change = None
        cut = self.window.cut(self.last_boundary)
        if cut is not None:
            self.cuts.append(cut)
            change = self._proposal()
        self._bound_models()
        return change

    # -- rules 2-5 -------------------------------------------------------------------------

    def _proposal(self) -> AreaTransition | None:
        """The change at the peak a few cuts back, if it is one and passes rule 3."""
        p = self.params
        settle = max(1, round(self.cuts[-1].ahead * p.settle_share))
        if len(self.cuts) <= settle:
            return None
        peak = self.cuts[-1 - settle]
        later = [c.score for c in list(self.cuts)[-settle:]]
        if peak.score < p.cut_min or peak.score <= max(later):
            return None
        earlier = [
            c.score
            for c in list(self.cuts)[: -1 - settle]
            if peak.boundary_seq - peak.width <= c.boundary_seq
        ]
        if max(earlier, default=0.0) > peak.score:
            return None
        if self.last_boundary is not None and peak.boundary_seq <= self.last_boundary:
            return None
        new = [f for s, f in self.window.frames if s >= peak.boundary_seq]
        return self._confirm(peak, new)

    def _confirm(self, peak: Cut, new: list[frozenset[int]]) -> AreaTransition | None:
        p = self.params
        moved: dict[int, int] = {}
        for frame in new:
            count(moved, frame)
        before = {f: c - moved.get(f, 0) for f, c in self.segment_counts.items()}
        before = {f: c for f, c in before.items() if c > 0}
        if len(before) < p.min_side_features or len(moved) < p.min_side_features:
            return None
        # Known before the window: the frames just before a boundary may stand past the door.
        older = [seq for seq, _ in self.window.frames if seq < peak.boundary_seq]
        recent: dict[int, int] = {}
        for seq, frame in self.window.frames:
            if seq >= older[-min(peak.width, len(older))]:
                count(recent, frame)
        area = self.areas[self.current]
        known = sum(1 for f in moved if area.get(f, 0) > recent.get(f, 0))
        # A strong cut backed by enough features is a change even if the area glimpsed the
        # room through its door; a turn among a handful of landmarks never has that backing.
        sure = peak.score >= p.sure_cut and len(moved) >= p.sure_features
        if known >= p.known_share * len(moved) and not sure:
            return None  # the area had seen nearly all of it before: the same place again
        return self._change(peak, moved, before)

    def _known_area(self, moved: dict[int, int]) -> tuple[int | None, float]:
        """The other area holding the largest share of the new half's features (rule 4)."""
        best, overlap = None, 0.0
        for area, counts in enumerate(self.areas):
            if area == self.current or not counts:
                continue
            share = sum(1 for f in moved if f in counts) / len(moved)
            if share > overlap:
                best, overlap = area, share
        return best, overlap

    def _change(self, peak: Cut, moved: dict[int, int], before: dict[int, int]) -> AreaTransition:
        """Close the segment at the peak's boundary and enter the named area (rules 4, 5)."""
        p = self.params
        boundary = peak.boundary_seq
        assert self.last_seq is not None
        new_frames = sum(1 for s in self.seqs if s >= boundary)
        left = self.current
        best, overlap = self._known_area(moved)
        revisit = best if best is not None and overlap >= p.revisit_overlap else None
        entered = revisit if revisit is not None else len(self.areas)
        if revisit is None:
            self.areas.append({})
            self.area_frames.append(0)
        # rule 5: the frames from the boundary on move to the segment and area entered
        left_counts = self.areas[left]
        for f, c in moved.items():
            left_counts[f] -= c
            if left_counts[f] <= 0:
                del left_counts[f]
        count_into = self.areas[entered]
        for f, c in moved.items():
            count_into[f] = count_into.get(f, 0) + c
        new_nonempty = sum(1 for s, _ in self.window.frames if s >= boundary)
        self.area_frames[left] -= new_nonempty
        self.area_frames[entered] += new_nonempty
        ncut, lambda2 = self.window.figures(boundary)
        candidate = Candidate(
            boundary_seq=boundary,
            seq=self.last_seq,
            reason=Reason.SPECTRAL,
            ncut=ncut,
            lambda2=lambda2,
            boundary_features=(),
        )
        first = self.segment_first_seq if self.segment_first_seq is not None else boundary
        transition = segment_transition(
            candidate,
            self.last_seq,
            self.last_stamp_s,
            closed=(self.segment_id, first, self.segment_frame_count - new_frames, before),
            opened=(new_frames, moved),
        )
        self.segment_id += 1
        self.segment_first_seq = boundary
        self.segment_frame_count = new_frames
        self.segment_counts = dict(moved)
        self.segment_nonempty = new_nonempty
        self.current = entered
        self.last_boundary = boundary
        self.transitions += 1
        return AreaTransition(
            transition=transition,
            area=entered,
            left_area=left,
            revisit_of=revisit,
            overlap=overlap if revisit is not None else 0.0,
            rule=Rule.SPLIT,
        )

    def _bound_models(self) -> None:
        """Rule 5: forget the smallest other areas' features above the bound."""
        bound = self.params.max_area_sightings
        if not bound or self.sightings <= bound:
            return
        order = sorted(
            (a for a in range(len(self.areas)) if a != self.current and self.areas[a]),
            key=lambda a: (self.area_frames[a], a),
        )
        total = self.sightings
        for area in order:
            if total <= bound * 3 // 4:
                break
            total -= len(self.areas[area])
            self.areas[area] = {}

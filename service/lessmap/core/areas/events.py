"""What an ``AreaTracker`` reports (``AreaTransition``) and keeps pending (``Candidate``)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

from lessmap.core.paper.submaps import Submap, Transition

if TYPE_CHECKING:
    from lessmap.core.paper.submaps import Reason


class Rule(StrEnum):
    """Which rule found an area change."""

    SPLIT = "split"  # a proposal of the paper's test, confirmed (rules 2-4)
    RECOGNISED = "recognised"  # the last frames fit a known area better (rule 5)


class AreaReason(StrEnum):
    """Why an area change was declared: the paper's two reasons, and recognition."""

    SPECTRAL = "SPECTRAL"  # a proposal passed Eq. 4 (the proposer's thresholds)
    DISCONNECTED = "DISCONNECTED"  # the proposer's CovGraph fell apart
    RECOGNISED = "RECOGNISED"  # the last frames fit a known area (rule 5): no Eq. 4 test


@dataclass(frozen=True, slots=True, kw_only=True)
class AreaTransition:
    """The robot left one area for another; ``transition`` in the paper's terms.

    ``transition.closed`` and ``transition.opened`` are the segments of frames on either
    side of the boundary (their ids count segments, from 0 per tracker); ``area`` and
    ``left_area`` name the areas those segments belong to.

    ``reason`` is why the change was declared. Read it rather than ``transition.reason``:
    the paper's ``Reason`` has no value for a recognised change, so such a change's
    ``transition`` says ``SPECTRAL``, with ``ncut`` and ``lambda2`` None because no Eq. 4
    test ran.
    """

    transition: Transition
    area: int  # the area entered
    left_area: int  # the area left
    revisit_of: int | None  # == area when the area was known before, else None
    overlap: float  # share of the new frames' features the entered area had seen (0: new)
    rule: Rule = Rule.SPLIT

    @property
    def reason(self) -> AreaReason:
        """Why the change was declared (``RECOGNISED`` for rule 5)."""
        if self.rule is Rule.RECOGNISED:
            return AreaReason.RECOGNISED
        return AreaReason(self.transition.reason.value)


@dataclass(frozen=True, slots=True, kw_only=True)
class Candidate:
    """A proposal waiting for confirmation (rule 3)."""

    boundary_seq: int  # first frame of the proposed new side
    seq: int  # frame at which the proposal was made
    reason: Reason
    ncut: float | None
    lambda2: float | None
    boundary_features: tuple[int, ...]


def segment_transition(
    candidate: Candidate,
    seq: int,
    stamp_s: float,
    *,
    closed: tuple[int, int, int, dict[int, int]],
    opened: tuple[int, dict[int, int]],
) -> Transition:
    """The paper's ``Transition`` of a confirmed change at ``candidate.boundary_seq``.

    Args:
        candidate: the change (boundary, reason, Eq. 4 figures, cut edges' endpoints).
        seq: the detection frame.
        stamp_s: its stamp.
        closed: the segment left: its id, first frame, frame count and features.
        opened: the segment entered (from the boundary to ``seq``): frame count, features.
    """
    segment_id, first, closed_frames, before = closed
    opened_frames, after = opened
    boundary = candidate.boundary_seq
    return Transition(
        seq=seq,
        boundary_seq=boundary,
        stamp_s=stamp_s,
        reason=candidate.reason,
        ncut=candidate.ncut,
        lambda2=candidate.lambda2,
        closed=Submap(
            id=segment_id,
            first_seq=first,
            last_seq=max(first, boundary - 1),
            frame_count=closed_frames,
            features=tuple(sorted(before)),
        ),
        opened=Submap(
            id=segment_id + 1,
            first_seq=boundary,
            last_seq=seq,
            frame_count=opened_frames,
            features=tuple(sorted(after)),
        ),
        boundary_features=candidate.boundary_features,
        batch_frames=1,
    )

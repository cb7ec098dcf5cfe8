"""What the partitioner reports: submaps, transitions and per-decision figures."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Reason(StrEnum):
    """Why a transition was declared."""

    SPECTRAL = "SPECTRAL"  # a bisection passed Eq. 4: Ncut <= Ncut_min and λ2 <= λ2_min
    DISCONNECTED = "DISCONNECTED"  # the CovGraph fell apart into components (§4.2.2)


@dataclass(frozen=True, slots=True, kw_only=True)
class Submap:
    """One area of the environment: its features and the frames spent in it."""

    id: int  # per session, from 0, in order of opening
    first_seq: int  # first frame in the area
    last_seq: int  # last frame in the area (so far, for the open submap)
    frame_count: int  # frames applied in [first_seq, last_seq], empty frames included
    features: tuple[int, ...]  # feature IDs, ascending


@dataclass(frozen=True, slots=True, kw_only=True)
class Transition:
    """The robot left one area for another: a validated bipartition of the CovGraph."""

    seq: int  # detection frame: the last frame the decision covered
    boundary_seq: int  # estimated first frame in the new area (<= seq)
    stamp_s: float  # stamp of the detection frame
    reason: Reason
    ncut: float | None  # None for DISCONNECTED
    lambda2: float | None  # None for DISCONNECTED
    closed: Submap  # the area left behind
    opened: Submap  # the area entered (its features so far)
    boundary_features: tuple[int, ...]  # endpoints of cut edges, ascending
    batch_frames: int  # frames covered by the decision (1 unless coalesced)


@dataclass(frozen=True, slots=True, kw_only=True)
class Evaluation:
    """The figures of one decision, transition or not (for monitoring and plots)."""

    seq: int
    nodes: int
    components: int
    ncut: float | None  # None when no bisection was computed
    lambda2: float | None
    transition: bool
    # Set instead of ncut and λ2 when the decision was settled by proving λ2 > this bound
    # (λ2_min) without the eigen-solve; see ``Partitioner(always_solve=...)``.
    lambda2_above: float | None = None

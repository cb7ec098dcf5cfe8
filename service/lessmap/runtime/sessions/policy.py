"""The kinds of decision a session table takes, each a frozen group of settings.

``Segmenting`` says what a new session runs; ``SessionLimits`` bounds memory and work;
``DurabilityPolicy`` says when sessions are checkpointed; ``CatchupPolicy`` how long frames
beyond a gap wait for the robot's cache; ``SharedBudgets`` are the instance-wide budgets the
shards share; ``Identity`` names who speaks (instance, partition epoch); ``Clocks`` time
decisions and stamp records.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lessmap.core.areas.tracker import AreaParams
from lessmap.core.segmenter import DEFAULT_METHOD, Method, make_segmenter

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.core import PartitionParams
    from lessmap.core.segmenter import Segmenter
    from lessmap.runtime.budget import EdgeLedger, SessionAdmission


def _never(_fleet: str) -> bool:
    return False


def _first_epoch(_fleet: str, _robot: str) -> int:
    return 1


@dataclass(frozen=True, slots=True, kw_only=True)
class Segmenting:
    """What a new session drives: the method and its parameters (a resumed one keeps its own)."""

    params: PartitionParams
    method: Method = DEFAULT_METHOD
    area_params: AreaParams = field(default_factory=AreaParams)
    # Per fleet: its robots leave out their empty frames, so stamp gaps are blindness.
    omits_empty_frames: Callable[[str], bool] = _never

    @property
    def max_features_kept(self) -> int:
        """What a new session's sampling keeps of a frame (0: all; only ``areas`` samples)."""
        return self.area_params.max_features_kept if self.method is Method.AREAS else 0

    def new_segmenter(self, fleet: str) -> Segmenter:
        """A fresh segmenter for a session of ``fleet``."""
        omitted = self.omits_empty_frames(fleet)
        areas = self.area_params.for_stream(empty_frames_omitted=omitted)
        return make_segmenter(self.method, self.params, areas)


@dataclass(frozen=True, slots=True, kw_only=True)
class SessionLimits:
    """Bounds on one shard's sessions: memory, work per frame, coalescing, idleness."""

    max_sessions: int  # open sessions per shard
    max_nodes: int  # features per CovGraph
    max_batch_frames: int  # frames applied before one decision (1: decide every frame)
    idle_timeout_s: float  # a session idle this long is evicted (or closed, memory-only)
    max_pairs_per_frame: int = 0  # 0: no budget
    max_edges_per_session: int = 0  # 0: no budget


@dataclass(frozen=True, slots=True, kw_only=True)
class DurabilityPolicy:
    """When a session is checkpointed (with a store that reaches a file)."""

    every_frames: int = 100
    interval_s: float = 10.0
    # Each robot's checkpoint clock starts at a phase of its own (``Durability.phase``).
    phased: bool = True


@dataclass(frozen=True, slots=True, kw_only=True)
class CatchupPolicy:
    """How frames beyond a gap wait for the robot's cache (``max_frames = 0``: they don't)."""

    max_frames: int = 0
    wait_s: float = 2.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SharedBudgets:
    """The budgets every shard of an instance shares, and this table's slot in the ledger."""

    ledger: EdgeLedger | None = None
    slot: int = 0
    admission: SessionAdmission | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class Identity:
    """Who the table's states and checkpoints come from."""

    instance: str
    # Epoch of a robot's partition at this instance, for states and checkpoints.
    epoch_of: Callable[[str, str], int] = _first_epoch


@dataclass(frozen=True, slots=True, kw_only=True)
class Clocks:
    """``decisions`` times the core's decisions; ``records`` stamps checkpoints (wall clock)."""

    decisions: Callable[[], float] = time.perf_counter
    records: Callable[[], float] = time.time

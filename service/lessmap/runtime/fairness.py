"""Deficit round robin over the robots of one shard: lanes, the coalescing level, turns.

Invariants (the why: ``docs/decisions/0004-fair-scheduling.md``):

1. Every round, each robot with pending messages gets a quantum of cost units (roughly pair
   updates: a frame costs its k(k-1)/2 pairs plus ``FRAME_COST``, a decision an estimate
   from its CovGraph's edges) and is served what its deficit affords.
2. A robot whose pending frames fit is decided every frame; one over its share is coalesced
   by its own load (one decision for the turn); when the shard is behind, only the robots
   asking more than a max-min fair share of the round's budget are coalesced.
3. Pure: no clock, no table, no I/O; the shard passes in what these need.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lessmap.runtime.budget import pairs_of
from lessmap.runtime.inbound import LIVE
from lessmap.runtime.sessions.model import FRAME_COST
from lessmap_schemas.messages import Frame

if TYPE_CHECKING:
    from collections import deque
    from collections.abc import Callable, Mapping

    from lessmap.runtime.inbound import Inbound
    from lessmap_schemas.messages import SessionEnd

# What one cost unit takes on the worker (docs/tuning/scheduler.md), to turn
# ``coalesce_after_s`` into a round's budget of cost units.
SECONDS_PER_COST_UNIT = 25e-9

# A planned message: (item, decoded message or None, its cost without a decision).
Planned = tuple["Inbound", "Frame | SessionEnd | None", int]


@dataclass(frozen=True, slots=True, kw_only=True)
class ShardPolicy:
    """A shard's queue bounds and how its worker schedules the robots."""

    queue_depth: int
    queue_bytes: int
    linger_s: float = 0.0  # a round woken by one frame waits this long for more
    quantum: int = 5_000_000  # cost units per robot and round (deficit round robin)
    coalesce_after_s: float = 0.05  # a frame older than this: the shard is behind
    heavy_of: int | None = None  # the index of the shard whose heavy lane this one is


@dataclass(slots=True)
class Lane:
    """One robot's pending messages in the shard, and its deficit (cost units)."""

    items: deque[Inbound]
    deficit: float = 0.0
    # The head item decoded (kept when the robot could not afford it this round).
    head: Frame | SessionEnd | None = None


def coalescing_level(
    lanes: Mapping[tuple[str, str], Lane],
    decision_cost: Callable[[tuple[str, str]], int],
    now: float,
    coalesce_after_s: float,
) -> float:
    """The per-frame demand above which a robot's turn shares its decisions this round.

    Infinite (the paper's loop for everyone) unless the shard is behind: the oldest pending
    frame waited longer than ``coalesce_after_s``. Then the round should take no more than
    that again, shared max-min fairly: the level L with sum(min(demand, L)) = budget, where
    a robot's demand is what deciding at each of its pending frames costs. L is never below
    the largest indivisible demand of the round (a robot's pending frames with one
    decision): a huge CovGraph then makes the others wait, but never changes their decisions.
    """
    # Replies and probes carry no receipt time (0.0): only live frames say how late we are.
    live = [lane.items[0].received_s for lane in lanes.values() if lane.items]
    oldest = min((t for t in live if t > 0.0), default=None)
    if oldest is None or now - oldest <= coalesce_after_s:
        return math.inf
    pending = [(len(lane.items), decision_cost(key)) for key, lane in lanes.items()]
    demands = sorted(n * (FRAME_COST + d) for n, d in pending)
    floor = max(n * FRAME_COST + d for n, d in pending)
    remaining = coalesce_after_s / SECONDS_PER_COST_UNIT
    for index, demand in enumerate(demands):
        share = remaining / (len(demands) - index)
        if demand > share:
            return max(share, floor)
        remaining -= demand
    return math.inf


def plan_turn(
    lane: Lane,
    decision: int,
    level: float,
    pending: int,
    decode: Callable[[Inbound], Frame | SessionEnd | None],
) -> tuple[list[Planned], bool, float]:
    """What a robot's deficit affords this turn: (plan, decided per frame, cost spent).

    ``pending`` is the lane's length when the turn began; its head, if live, is decoded
    already (``lane.head``); ``decode`` returns None for a message that does not decode
    (the plan stops there: it is reported when it reaches the head).
    """
    plan: list[Planned] = []
    total = 0  # cost of the planned messages, decisions left out
    # A decision after every message, unless the shard is behind and this robot asks more
    # than its fair share of the round (``coalescing_level``).
    fits_per_frame = pending * (FRAME_COST + decision) <= level
    for index, item in enumerate(lane.items):
        message: Frame | SessionEnd | None = None
        if item.kind == LIVE:
            message = lane.head if index == 0 else decode(item)
            if message is None:
                break
        cost = FRAME_COST
        if isinstance(message, Frame):
            cost += pairs_of(len(message.features))
        if fits_per_frame and total + cost + (index + 1) * decision > lane.deficit:
            fits_per_frame = False
        if not fits_per_frame and total + cost + decision > lane.deficit:
            break  # the rest waits for the next round (or more credit)
        total += cost
        plan.append((item, message, cost))
    spent = total + (len(plan) if fits_per_frame else 1) * decision
    return plan, fits_per_frame, spent

"""A shard's heavy lane: robots whose decisions take long, served by a worker of their own.

Invariants (the why and the bound: ``docs/design/heavy-robots.md``):

1. A robot moves to the heavy lane when one decision of its session, estimated from its
   CovGraph's edges plus the pairs its session keeps (after sampling) of the frame at the
   head of its lane, would take longer than ``heavy_decision_ms``; it stays there while
   this instance runs.
2. The move is a pair of commands: the shard's worker releases the robot from its table,
   then the heavy worker adopts it, before any message of the robot reaches the heavy
   worker (sent first, taken first); one owner per session at every moment.
3. From then on the shard's worker forwards the robot's messages, still raw and in arrival
   order, to the heavy worker's queue; a message that queue refuses is reported as a full
   queue is, and left to the robot's cache.
4. Commands that must reach every session (drain, hand-over, stop) reach the heavy worker
   after the shard's worker forwarded what it held.
"""

from __future__ import annotations

import logging
from concurrent.futures import Future
from typing import TYPE_CHECKING, Generic, Protocol, TypeVar

from lessmap.runtime.fairness import SECONDS_PER_COST_UNIT
from lessmap_schemas.errors import ErrorCode

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.runtime.inbound import Inbound
    from lessmap.runtime.sessions.model import MovedRobot

log = logging.getLogger(__name__)

A = TypeVar("A")


class Worker(Protocol):
    """What the heavy lane needs of its worker (a ``Shard``, named here without a cycle)."""

    @property
    def index(self) -> int:
        """The worker's index (logs)."""

    def offer_many(self, items: list[Inbound]) -> list[Inbound]:
        """Enqueue items in order without blocking; return those refused."""

    def note_rejection(self, key: str, code: ErrorCode, detail: str) -> None:
        """Record a refused sample; the worker reports it."""

    def adopt(self, moved: MovedRobot) -> Future[None]:
        """Take a robot another worker released."""


W = TypeVar("W", bound=Worker)

_ROBOTS_KEPT = 65_536  # robots moved, at most: past it new heavy robots stay in the shard


def cost_of_ms(decision_ms: float) -> float:
    """A decision time in the scheduler's cost units (0 or less: never)."""
    return decision_ms / 1000.0 / SECONDS_PER_COST_UNIT if decision_ms > 0 else float("inf")


class HeavyLane(Generic[W]):
    """Which robots of a shard are heavy, and the worker that serves them."""

    def __init__(self, worker: W, decision_ms: float) -> None:
        self.worker = worker
        self.robots: set[tuple[str, str]] = set()  # the shard's worker's alone
        self._after_cost = cost_of_ms(decision_ms)

    def is_heavy(self, decision_cost: int) -> bool:
        """Whether a decision of this estimated cost, head frame included, is too long (inv. 1)."""
        return decision_cost > self._after_cost and len(self.robots) < _ROBOTS_KEPT

    def move(self, key: tuple[str, str], moved: MovedRobot, items: list[Inbound]) -> None:
        """Hand a released robot and its pending messages to the heavy worker (invariant 2)."""
        self.worker.adopt(moved)  # sent before any of its messages
        self.robots.add(key)
        self.forward(items)
        log.info("%s/%s moved to the heavy lane of shard %d", *key, self.worker.index)

    def forward(self, items: list[Inbound]) -> None:
        """Hand a heavy robot's messages to the heavy worker (invariant 3)."""
        worker = self.worker
        for item in worker.offer_many(items):
            detail = f"heavy lane of shard {worker.index} full; message dropped"
            worker.note_rejection(item.key, ErrorCode.LIMIT_EXCEEDED, detail)


def and_heavy(
    first: Future[A],
    lane: HeavyLane[W] | None,
    command: Callable[[W], Future[A]],
    combine: Callable[[A, A], A],
) -> Future[A]:
    """``first``, then ``command`` sent to the heavy worker, results combined (invariant 4).

    The command is sent when ``first`` is done (what the shard's worker forwarded is then
    queued ahead of it); nothing here blocks a worker.
    """
    if lane is None:
        return first
    out: Future[A] = Future()

    def on_first(done: Future[A]) -> None:
        error = done.exception()
        if error is not None:
            out.set_exception(error)
            return
        mine = done.result()

        def on_heavy(heavy_done: Future[A]) -> None:
            heavy_error = heavy_done.exception()
            if heavy_error is not None:
                out.set_exception(heavy_error)
            else:
                out.set_result(combine(mine, heavy_done.result()))

        command(lane.worker).add_done_callback(on_heavy)

    first.add_done_callback(on_first)
    return out

"""What a shard's queue holds, sorted into its robots' lanes: the first step of a round.

Invariants:

1. Runs on the shard's worker only; the queue's lock is held while items move, never while
   anything is published.
2. A robot's messages keep their arrival order, in its lane or on the way to the heavy lane.
3. A key that names no robot is reported once, outside the lock, and released.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Any

from lessmap.runtime.fairness import Lane
from lessmap_schemas.errors import WireError
from lessmap_schemas.keys import parse_robot_key

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.runtime.heavy import HeavyLane
    from lessmap.runtime.inbound import Inbound, InboundQueue

BATCH_MAX = 4096  # messages moved from the queue to the lanes per call
_KEYS_REMEMBERED = 65_536  # parsed robot keys kept


class Arrivals:
    """Moves a shard's queued messages into its robots' lanes (or its heavy lane)."""

    def __init__(
        self,
        inbound: InboundQueue,
        lanes: dict[tuple[str, str], Lane],
        heavy: HeavyLane[Any] | None,
        reject_unattributed: Callable[[str, WireError], None],
    ) -> None:
        self._inbound = inbound
        self._lanes = lanes  # the shard's: insertion order = round order
        self._heavy = heavy
        self._reject_unattributed = reject_unattributed
        self._robot_of: dict[str, tuple[str, str]] = {}  # valid keys seen: (fleet, robot)

    def move_queued(self) -> None:
        """Move everything queued now (not what arrives meanwhile)."""
        for _ in range(-(-len(self._inbound.queue) // BATCH_MAX)):
            self.move()

    def move(self) -> None:
        """Move what the queue holds into the robots' lanes (at most ``BATCH_MAX``)."""
        unattributed: list[tuple[str, WireError]] = []
        robot_of = self._robot_of
        lanes = self._lanes
        inbound = self._inbound
        heavy = self._heavy.robots if self._heavy is not None else ()
        forwarded: list[Inbound] = []
        with inbound.cond:
            queue = inbound.queue
            for _ in range(min(len(queue), BATCH_MAX)):
                item = queue.popleft()
                robot_key = robot_of.get(item.key)
                if robot_key is None:
                    try:
                        robot_key = self._parse_key(item.key)
                    except WireError as exc:
                        inbound.release([item])
                        unattributed.append((item.key, exc))
                        continue
                if robot_key in heavy:
                    forwarded.append(item)
                    continue
                lane = lanes.get(robot_key)
                if lane is None:
                    lane = lanes[robot_key] = Lane(deque())
                lane.items.append(item)
            inbound.release(forwarded)
        if forwarded and self._heavy is not None:
            self._heavy.forward(forwarded)
        for key, error in unattributed:  # outside the lock: the callback never waits on a put
            self._reject_unattributed(key, error)

    def forget_keys(self) -> None:
        """Drop the parsed keys (sessions left memory: so do their keys' strings)."""
        self._robot_of.clear()

    def _parse_key(self, key: str) -> tuple[str, str]:
        """Return (fleet, robot) of a frames key, remembered: a robot's key arrives often."""
        fleet, robot, _stream = parse_robot_key(key)
        if len(self._robot_of) >= _KEYS_REMEMBERED:
            self._robot_of.clear()  # a churn of robots: start over rather than grow
        robot_key = self._robot_of[key] = (fleet, robot)
        return robot_key

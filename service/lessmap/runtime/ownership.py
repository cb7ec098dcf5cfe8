"""Which partitions this instance owns, from the live instances it sees (no I/O here).

Invariants (``schemas/README.md`` section 2a; ``docs/decisions/0007-fence-and-epochs.md``):

1. The live instance names are ranked per partition by rendezvous hashing: the first owns
   the partition, the second is its standby.
2. The fence: ``epoch_for(fleet, robot)`` is the epoch of the robot's partition while this
   instance owns it and is sure of it, ``None`` otherwise; nothing is published without one.
3. Sure of it: a heartbeat (``tick``) proves the process was not frozen; after ``freeze_s``
   without one the fence closes at once and every partition is dropped, to be taken back
   under new epochs.
4. An epoch is at least the wall clock in milliseconds and above every epoch known for the
   partition, so a new owner's epoch is above its predecessor's.
"""

from __future__ import annotations

import functools
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lessmap_schemas.partition import PARTITIONS, owner_and_standby, partition_of

# A robot's partition, remembered: every frame asks whether its robot is still owned, and
# hashing the name cost 2.6 % of a shard at 200 robots. Bounded, so a churn of robot names
# (a session flood) keeps a few thousand small strings at most.
_partition_of = functools.lru_cache(maxsize=4096)(partition_of)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable


@dataclass(frozen=True, slots=True)
class Change:
    """What a new view of the live instances changes for this instance."""

    gained: list[int] = field(default_factory=list)
    lost: list[int] = field(default_factory=list)
    standby_gained: list[int] = field(default_factory=list)
    standby_lost: list[int] = field(default_factory=list)
    # Gained partitions that a live instance owned in the view before: that instance hands
    # each over when it sees the same change, and says so (``keys.released``).
    handed_by: dict[int, str] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return bool(self.gained or self.lost or self.standby_gained or self.standby_lost)


class Ownership:
    """Partitions owned and stood by for; the fence for publishing (thread-safe)."""

    def __init__(
        self,
        instance: str,
        *,
        freeze_s: float = 2.0,
        monotonic: Callable[[], float] = time.monotonic,
        wall_ms: Callable[[], int] = lambda: int(time.time() * 1000),
    ) -> None:
        self.instance = instance
        self.freeze_s = freeze_s
        self._monotonic = monotonic
        self._wall_ms = wall_ms
        self._lock = threading.Lock()
        self._live: set[str] = {instance}
        self._owned: dict[int, int] = {}  # partition -> epoch, partitions taken and active
        self._standby: set[int] = set()
        self._known_epoch: dict[int, int] = {}  # highest epoch seen per partition
        self._last_tick = monotonic()
        self.freezes = 0

    # -- the live view -----------------------------------------------------------------------

    @property
    def live(self) -> frozenset[str]:
        """Instances believed alive (this one included)."""
        with self._lock:
            return frozenset(self._live)

    def set_live(self, instances: Iterable[str], *, arriving: bool = False) -> Change:
        """Replace the live set (this instance is always in it); return what changes.

        ``arriving``: this instance's token is new to the others (start-up). They own, among
        themselves, the partitions it wins until they see it; ``Change.handed_by`` names them.
        """
        with self._lock:
            before = frozenset(instances) - {self.instance} if arriving else frozenset(self._live)
            self._live = {*instances, self.instance}
            live = frozenset(self._live)
        return self._diff(live, before)

    def join(self, instance: str) -> Change:
        """An instance's token appeared."""
        with self._lock:
            before = frozenset(self._live)
            self._live.add(instance)
            live = frozenset(self._live)
        return self._diff(live, before)

    def leave(self, instance: str) -> Change:
        """An instance's token went away (never this one: its own token is its own)."""
        with self._lock:
            before = frozenset(self._live)
            if instance != self.instance:
                self._live.discard(instance)
            live = frozenset(self._live)
        return self._diff(live, before)

    def _diff(self, live: frozenset[str], before: frozenset[str]) -> Change:
        # The ranking (a hash per instance and partition) runs outside the lock: the fence
        # takes it for every incoming frame. One thread applies changes, so nothing else
        # moves the owned set meanwhile.
        should_own: set[int] = set()
        should_stand: set[int] = set()
        for p in range(PARTITIONS):
            owner, standby = owner_and_standby(p, live)
            if owner == self.instance:
                should_own.add(p)
            elif standby == self.instance:
                should_stand.add(p)
        with self._lock:
            owned = set(self._owned)
            standing = set(self._standby)
        gained = sorted(should_own - owned)
        return Change(
            gained=gained,
            lost=sorted(owned - should_own),
            standby_gained=sorted(should_stand - standing),
            standby_lost=sorted(standing - should_stand),
            handed_by=self._former_owners(gained, live, before),
        )

    def _former_owners(
        self, gained: list[int], live: frozenset[str], before: frozenset[str]
    ) -> dict[int, str]:
        """The live instance that owned each gained partition in the view ``before``.

        Rendezvous ranks two instances alike whoever else is alive, so an instance that
        outranked this one keeps doing so: only this instance's own arrival moves a
        partition away from a live owner (a leave moves the partitions of the one that left).
        """
        if not before:
            return {}
        handed: dict[int, str] = {}
        for p in gained:
            former, _ = owner_and_standby(p, before)
            if former is not None and former != self.instance and former in live:
                handed[p] = former
        return handed

    # -- applying a change (the service does the I/O in between) -----------------------------

    def release(self, partition: int) -> None:
        """Stop owning a partition: the fence closes for it at once."""
        with self._lock:
            self._owned.pop(partition, None)

    def acquire(self, partition: int) -> int:
        """Own a partition under a new epoch; return the epoch."""
        with self._lock:
            epoch = max(self._wall_ms(), self._known_epoch.get(partition, 0) + 1)
            self._known_epoch[partition] = epoch
            self._owned[partition] = epoch
            return epoch

    def set_standby(self, partition: int, on: bool) -> None:
        """Record that this instance is (or no longer is) the partition's standby."""
        with self._lock:
            if on:
                self._standby.add(partition)
            else:
                self._standby.discard(partition)

    def saw_epoch(self, partition: int, epoch: int) -> None:
        """Remember an epoch of the partition seen elsewhere (a checkpoint taken over)."""
        with self._lock:
            if epoch > self._known_epoch.get(partition, 0):
                self._known_epoch[partition] = epoch

    # -- the fence ---------------------------------------------------------------------------

    def start_clock(self) -> None:
        """Start the heartbeat clock (when the heartbeat starts; no freeze before it)."""
        with self._lock:
            self._last_tick = self._monotonic()

    def tick(self) -> bool:
        """Heartbeat; True when a freeze was detected (every partition was dropped)."""
        now = self._monotonic()
        with self._lock:
            frozen = now - self._last_tick > self.freeze_s
            if frozen:
                self.freezes += 1
                self._owned.clear()
                self._standby.clear()
            self._last_tick = now
            return frozen

    def epoch_for(self, fleet: str, robot: str) -> int | None:
        """The epoch to publish under for this robot, or None: do not publish."""
        return self.epoch_of(_partition_of(fleet, robot))

    def epoch_of(self, partition: int) -> int | None:
        """The partition's epoch while owned and not frozen, else None."""
        with self._lock:
            if self._monotonic() - self._last_tick > self.freeze_s:
                return None
            return self._owned.get(partition)

    def last_epoch(self, fleet: str, robot: str) -> int:
        """The latest epoch this instance knows for the robot's partition (1 if none).

        For the records this instance writes (checkpoints, states): whether it may publish
        them is ``epoch_for``'s question.
        """
        with self._lock:
            return self._known_epoch.get(_partition_of(fleet, robot), 1)

    def owns(self, fleet: str, robot: str) -> bool:
        """True while this instance owns the robot's partition (the fence aside)."""
        with self._lock:
            return _partition_of(fleet, robot) in self._owned

    def owned(self) -> dict[int, int]:
        """Owned partitions and their epochs."""
        with self._lock:
            return dict(self._owned)

    def standby(self) -> list[int]:
        """Partitions this instance stands by for, ascending."""
        with self._lock:
            return sorted(self._standby)

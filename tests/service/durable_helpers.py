"""Builders for the durable-session tests: a simulated walk, a committing table, a store.

The session table and the store are real (a SQLite file under ``tmp_path``); a "restart"
is a new store and a new table on the same folder, a "crash" drops the old ones without
stopping them. The reference is one table that never stopped. The service saves an outcome's
checkpoints once it published the outcome; ``CommittingTable`` does the same at once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from lessmap.core import PartitionParams
from lessmap.runtime.sessions import (
    CatchupPolicy,
    DurabilityPolicy,
    Identity,
    Outcome,
    Segmenting,
    SessionLimits,
    SessionTable,
    commit_checkpoints,
)
from lessmap.runtime.store import CheckpointStore
from lessmap.sim.simulator import simulate
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Frame

if TYPE_CHECKING:
    from pathlib import Path


LASER = PartitionParams.from_profile("laser")
FLEET = "fleet"
ROBOT = "robot0"
SESSION = "s1"


def walk() -> list[Frame]:
    """One simulated robot walking an 8-room building: several transitions."""
    run = simulate(3, rooms=8, robots=1, frames_per_robot=400)
    return [
        Frame(session=SESSION, seq=f["seq"], stamp_s=f["stamp"], features=f["features"])
        for f in run.frames
    ]


FRAMES = walk()


class CommittingTable(SessionTable):
    """A session table whose outcomes' checkpoints are saved as soon as they are returned."""

    def __init__(
        self,
        store: CheckpointStore | None,
        segmenting: Segmenting,
        limits: SessionLimits,
        **policies: Any,
    ) -> None:
        super().__init__(segmenting, limits, store=store, **policies)
        self.committed_to = store

    def _committed(self, out: Outcome) -> Outcome:
        if self.committed_to is not None:
            commit_checkpoints(out, self.committed_to)
        return out

    def handle_batch(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().handle_batch(*args, **kwargs))

    def recover(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().recover(*args, **kwargs))

    def catchup_done(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().catchup_done(*args, **kwargs))

    def release_overdue(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().release_overdue(*args, **kwargs))

    def expire_idle(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().expire_idle(*args, **kwargs))

    def close_all(self, *args: Any, **kwargs: Any) -> Outcome:
        return self._committed(super().close_all(*args, **kwargs))


def make_table(
    store: CheckpointStore | None,
    *,
    every: int = 25,
    phase: bool = False,
    catchup_max_frames: int = 0,  # 0: no catch-up (the table's default)
    catchup_wait_s: float = 2.0,
) -> SessionTable:
    # phase=False: checkpoints at exact multiples of ``every``, which the tests below pin.
    return CommittingTable(
        store,
        Segmenting(params=LASER),
        SessionLimits(max_sessions=8, max_nodes=20_000, max_batch_frames=1, idle_timeout_s=10.0),
        identity=Identity(instance="test"),
        durability=DurabilityPolicy(every_frames=every, interval_s=3600.0, phased=phase),
        catchup=CatchupPolicy(max_frames=catchup_max_frames, wait_s=catchup_wait_s),
    )


def open_store(folder: Path) -> CheckpointStore:
    store = CheckpointStore(folder)
    store.open()
    return store


def feed(table: SessionTable, frames: list[Frame], now_s: float = 0.0) -> list[Outcome]:
    return [table.handle_batch([(FLEET, ROBOT, f)], now_s) for f in frames]


def transitions(outcomes: list[Outcome]) -> list[tuple[int, int, tuple[int, ...]]]:
    """(seq, closed submap id, closed features) of every transition."""
    return [
        (c.transition.seq, c.transition.closed.id, tuple(c.transition.closed.features))
        for o in outcomes
        for _, c in o.transitions
    ]


def errors(outcomes: list[Outcome]) -> list[ErrorCode]:
    return [r.code for o in outcomes for r in o.rejections]


REFERENCE = transitions(feed(make_table(None), FRAMES))


def crash(store: CheckpointStore) -> None:
    """What the kernel does for a process killed with -9: its files close, its lock goes."""
    lock = store._lock_file  # the test plays the kernel
    if lock is not None:
        lock.close()

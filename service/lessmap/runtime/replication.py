"""Checkpoints between instances: the standby's copies, a take-over's fetch, the answers.

Invariants:

1. An owner's checkpoints leave through the outbox (``Outbox`` ships each one it commits,
   after the transitions it covers); this module only receives, fetches and answers.
2. A checkpoint shipped or returned by another instance is kept only if it is newer than
   what the store holds (epoch, then seq), and never for a partition this instance owns
   (a deposed owner's late checkpoint).
3. A take-over asks every instance for the partitions' checkpoints and waits at most
   ``handover_fetch_s``; what did not come in time is left to the robots' caches.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import TYPE_CHECKING

import zenoh

from lessmap.runtime.record import SessionRecord
from lessmap_schemas import keys
from lessmap_schemas.errors import WireError
from lessmap_schemas.partition import partition_of

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from lessmap.runtime.metrics import ServiceMetrics
    from lessmap.runtime.ownership import Ownership
    from lessmap.runtime.store import CheckpointStore

log = logging.getLogger(__name__)

CHECKPOINT_ENCODING = zenoh.Encoding("application/octet-stream")


class Replication:
    """The standby subscriptions, the checkpoint fetch of a take-over, checkpoint answers."""

    def __init__(
        self,
        store: CheckpointStore,
        ownership: Ownership,
        metrics: ServiceMetrics,
        *,
        fetch_wait_s: float,
    ) -> None:
        self.store = store
        self._ownership = ownership
        self._metrics = metrics
        self._fetch_wait_s = fetch_wait_s
        self._standby_subs: dict[int, zenoh.Subscriber[None]] = {}

    # -- standby ---------------------------------------------------------------------------

    def stand_by(
        self, session: zenoh.Session, partition: int, on_sample: Callable[[zenoh.Sample], None]
    ) -> None:
        """Subscribe to the checkpoints the owner of ``partition`` ships (with a store)."""
        if self.store.path is not None and partition not in self._standby_subs:
            self._standby_subs[partition] = session.declare_subscriber(
                keys.checkpoints(partition), on_sample
            )

    def stop_standing_by(self, partitions: Sequence[int] | None = None) -> None:
        """Undeclare the standby subscriptions of ``partitions`` (None: all)."""
        for p in list(self._standby_subs) if partitions is None else partitions:
            sub = self._standby_subs.pop(p, None)
            if sub is not None:
                sub.undeclare()

    def take_replica(self, key: str, payload: bytes) -> None:
        """Keep a checkpoint the owner shipped (the ownership thread), unless ours (inv. 2)."""
        p = key.split("/")[4] if key.count("/") >= 4 else ""
        if p.isdigit() and self._ownership.epoch_of(int(p)) is not None:
            return  # this instance owns it: a deposed owner's late checkpoint
        self.store_replica(key, payload)

    def store_replica(self, key: str, payload: bytes) -> bool:
        """Keep a checkpoint shipped or returned by another instance, if it is newer."""
        try:
            partition, fleet, robot = keys.parse_checkpoint_key(key)
            record = SessionRecord.from_bytes(payload)
        except (WireError, ValueError) as exc:
            log.warning("ignored a checkpoint on %s: %s", key[:200], exc)
            return False
        if record.key != (fleet, robot):
            log.warning("ignored a checkpoint on %s: it is %s/%s's", key[:200], *record.key)
            return False
        self._ownership.saw_epoch(partition, record.epoch)
        if self.store.offer(record):
            self._metrics.checkpoints_received.inc()
            return True
        return False

    # -- take-over ---------------------------------------------------------------------------

    def fetch(self, session: zenoh.Session | None, partitions: Sequence[int]) -> int:
        """Ask every instance for the partitions' checkpoints; keep the newest per robot.

        Memory-only instances ask too: a hand-over's records are on the old owner's shelf.
        Their own shelf's records of these partitions go first: handed out earlier, they
        are older than the session's state wherever it ran since (or it was lost with it).
        """
        if self.store.shelf is not None:
            moving = set(partitions)
            self.store.shelf.drop_where(lambda fleet, robot: partition_of(fleet, robot) in moving)
        if session is None or len(self._ownership.live) < 2:
            return 0
        replies: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        ended = threading.Semaphore(0)

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh's thread: enqueue only
            if reply.ok is not None:
                replies.put((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))

        def on_end() -> None:
            ended.release()

        wait_s = self._fetch_wait_s
        asked = 0
        for p in partitions:
            try:
                session.get(
                    keys.checkpoints(p),
                    zenoh.handlers.Callback(on_reply, on_end),
                    target=zenoh.QueryTarget.ALL,
                    consolidation=zenoh.ConsolidationMode.NONE,
                    timeout=wait_s,
                )
                asked += 1
            except zenoh.ZError as exc:
                log.warning("checkpoint query of partition %d failed: %s", p, exc)
        deadline = time.monotonic() + wait_s + 0.5
        for _ in range(asked):
            if not ended.acquire(timeout=max(0.0, deadline - time.monotonic())):
                log.warning("checkpoint queries unanswered after %.1f s; going on", wait_s)
                break
        taken = 0
        while not replies.empty():
            key, payload = replies.get()
            if self.store_replica(key, payload):
                taken += 1
        return taken

    # -- answers -----------------------------------------------------------------------------

    def reply(self, query: zenoh.Query) -> None:
        """Answer with the checkpoints this instance holds that the selector asks for."""
        selector = query.key_expr
        chunks = str(selector).split("/")
        wanted = int(chunks[4]) if len(chunks) > 4 and chunks[4].isdigit() else None

        def asked(fleet: str, robot: str) -> bool:
            p = partition_of(fleet, robot)
            if wanted is not None and p != wanted:
                return False
            return selector.intersects(zenoh.KeyExpr(keys.checkpoints(p, fleet, robot)))

        for record in self.store.records_where(asked):
            key = keys.checkpoints(partition_of(record.fleet, record.robot), *record.key)
            query.reply(key, record.to_bytes(), encoding=CHECKPOINT_ENCODING)

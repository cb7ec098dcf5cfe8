"""A shard: one inbound queue, one worker thread, the sessions of the robots hashed to it.

The receive path never blocks Zenoh: the subscriber callback only measures the sample and
appends it to a shard's queue (bounded in messages and in bytes). The worker drains the
queue in batches, decodes, hands the batch to its ``SessionTable`` (which coalesces the
spectral decisions of each session) and publishes what came out. A robot always hashes to
the same shard, so its frames are handled in order by one thread; shards share nothing but
the Zenoh session and the metrics.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lessmap.runtime.sessions import Outcome, Rejection, SessionTable
from lessmap_schemas.codec import decode_inbound
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.keys import parse_robot_key

if TYPE_CHECKING:
    from lessmap.runtime.outbox import Outbox
    from lessmap_schemas.limits import WireLimits
    from lessmap_schemas.messages import Frame, SessionEnd

log = logging.getLogger(__name__)

_BATCH_MAX = 4096  # messages taken from the queue per round: bounds one round's latency
_LINGER_BELOW = 64  # a queue this deep already makes a batch: no lingering
_IDLE_SWEEP_S = 1.0


@dataclass(frozen=True, slots=True)
class Inbound:
    """One raw sample as the callback saw it."""

    received_s: float  # time.monotonic() at receipt
    key: str
    payload: bytes


class Shard:
    """Owns a queue, a worker thread and a session table."""

    def __init__(
        self,
        index: int,
        table: SessionTable,
        outbox: Outbox,
        *,
        limits: WireLimits,
        queue_depth: int,
        queue_bytes: int,
        linger_s: float = 0.0,
    ) -> None:
        self.index = index
        self.table = table
        self.lock = threading.Lock()  # guards ``table`` between the worker and queries
        self._outbox = outbox
        self._limits = limits
        self._queue: deque[Inbound] = deque()
        self._queue_depth = queue_depth
        self._queue_bytes = queue_bytes
        self._queued_bytes = 0
        self._linger_s = linger_s
        self._ready = threading.Condition()
        self._stopping = False
        self._thread = threading.Thread(
            target=self._run, name=f"lessmap-shard-{index}", daemon=True
        )
        self._last_sweep_s = time.monotonic()
        # Rejections decided on Zenoh's thread (queue full, payload too large), published by
        # the worker; deque appends are atomic, and maxlen bounds a flood.
        self._notes: deque[tuple[str, ErrorCode, str]] = deque(maxlen=10_000)

    # -- receive path (Zenoh's thread) -------------------------------------------------------

    def offer(self, item: Inbound) -> bool:
        """Enqueue a sample without blocking; False when the shard is full (caller reports)."""
        size = len(item.payload)
        with self._ready:
            if (
                self._stopping
                or len(self._queue) >= self._queue_depth
                or self._queued_bytes + size > self._queue_bytes
            ):
                return False
            self._queue.append(item)
            self._queued_bytes += size
            self._ready.notify()
        return True

    def note_rejection(self, key: str, code: ErrorCode, detail: str) -> None:
        """Record a sample refused on the receive path; the worker reports it."""
        self._notes.append((key, code, detail))
        with self._ready:
            self._ready.notify()

    def depth(self) -> int:
        """Messages waiting."""
        return len(self._queue)

    # -- worker ------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the worker thread."""
        self._thread.start()

    def stop(self, timeout_s: float) -> None:
        """Let the worker finish what is queued, then end it."""
        with self._ready:
            self._stopping = True
            self._ready.notify()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("shard %d did not drain within %.1f s", self.index, timeout_s)

    def _take(self) -> list[Inbound]:
        with self._ready:
            while not self._queue and not self._stopping and not self._notes:
                self._ready.wait(timeout=_IDLE_SWEEP_S / 2)
                if not self._queue:
                    break
            linger = 0 < len(self._queue) < _LINGER_BELOW and not self._stopping
        if linger and self._linger_s > 0:
            # Woken by one frame: let the next few milliseconds of frames join this round.
            # A wake-up per frame costs as much CPU as the frame's own work at fleet rates.
            time.sleep(self._linger_s)
        with self._ready:
            batch: list[Inbound] = []
            while self._queue and len(batch) < _BATCH_MAX:
                item = self._queue.popleft()
                self._queued_bytes -= len(item.payload)
                batch.append(item)
            return batch

    def _run(self) -> None:
        while True:
            batch = self._take()
            if self._notes:
                self._report_notes()
            if batch:
                try:
                    self._process(batch)
                except Exception:
                    # A bug must not kill the shard: log it, keep serving the other sessions.
                    log.exception("shard %d failed on a batch of %d", self.index, len(batch))
            now = time.monotonic()
            if now - self._last_sweep_s >= _IDLE_SWEEP_S:
                self._last_sweep_s = now
                with self.lock:
                    expired = self.table.expire_idle(now)
                self._outbox.publish(expired, now)
            with self._ready:
                if self._stopping and not self._queue:
                    return

    def _report_notes(self) -> None:
        outcome = Outcome()
        while self._notes:
            key, code, detail = self._notes.popleft()
            try:
                fleet, robot, _stream = parse_robot_key(key)
            except WireError as exc:
                self._outbox.reject_unattributed(key, exc)
                continue
            outcome.rejections.append(Rejection(fleet, robot, None, code, detail, None))
        self._outbox.publish(outcome, time.monotonic())

    def _process(self, batch: list[Inbound]) -> None:
        now = time.monotonic()
        decoded: list[tuple[str, str, Frame | SessionEnd]] = []
        rejections: list[Rejection] = []
        for item in batch:
            self._outbox.metrics.queue_latency_seconds.observe(now - item.received_s)
            try:
                fleet, robot, _stream = parse_robot_key(item.key)
            except WireError as exc:
                self._outbox.reject_unattributed(item.key, exc)
                continue
            try:
                message = decode_inbound(item.payload, self._limits)
            except WireError as exc:
                rejections.append(Rejection(fleet, robot, None, exc.code, str(exc), None))
                continue
            log.debug(
                "<<- %s %s seq=%s", item.key, type(message).__name__, getattr(message, "seq", None)
            )
            decoded.append((fleet, robot, message))
        with self.lock:
            outcome = self.table.handle_batch(decoded, now)
        outcome.rejections[:0] = rejections
        self._outbox.publish(outcome, now)
        done = time.monotonic()
        frame_latency = self._outbox.metrics.frame_latency_seconds
        for item in batch:
            frame_latency.observe(done - item.received_s)
        self._outbox.metrics.queue_depth.set(len(self._queue))

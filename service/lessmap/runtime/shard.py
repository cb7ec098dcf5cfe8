"""A shard: one inbound queue, one worker thread, the sessions of the robots hashed to it.

The receive path never blocks Zenoh: the subscriber callback only measures the sample and
appends it to a shard's queue (bounded in messages and in bytes). The worker drains the
queue in batches, decodes, hands the batch to its ``SessionTable`` (which coalesces the
spectral decisions of each session) and publishes what came out. A robot always hashes to
the same shard, so its frames are handled in order by one thread; shards share nothing but
the Zenoh session and the metrics.

Catch-up: when the table holds frames beyond a gap it returns ``CatchupRequest``s; the worker
hands them to ``request_catchup`` (the service sends a Zenoh query with callbacks and
returns at once). The query's replies come back through ``offer`` as ``RECOVERED`` items and
its end as one ``CATCHUP_DONE`` item (admitted past the depth bound, so a full queue cannot
leave a hold waiting): the same FIFO, so the end is always taken after the replies.
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
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.runtime.outbox import Outbox
    from lessmap.runtime.sessions import CatchupRequest
    from lessmap_schemas.limits import WireLimits

log = logging.getLogger(__name__)

_BATCH_MAX = 4096  # messages taken from the queue per round: bounds one round's latency
_LINGER_BELOW = 64  # a queue this deep already makes a batch: no lingering
_IDLE_SWEEP_S = 1.0

LIVE = 0  # a sample of the frames subscriber
RECOVERED = 1  # a reply of a robot's publication cache to a catch-up query
CATCHUP_DONE = 2  # the end of a catch-up query; the payload is the session id (UTF-8)


@dataclass(frozen=True, slots=True)
class Inbound:
    """One raw sample as the callback saw it."""

    received_s: float  # time.monotonic() at receipt
    key: str
    payload: bytes
    kind: int = LIVE


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
        request_catchup: Callable[[Shard, CatchupRequest], None] | None = None,
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
        self._request_catchup = request_catchup
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
        """Enqueue a sample without blocking; False when the shard is full (caller reports).

        The end of a catch-up query is always taken (one per query under way, each a few
        bytes), so a hold never outlives its query because the queue was full.
        """
        size = len(item.payload)
        with self._ready:
            if item.kind != CATCHUP_DONE and (
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
            if self.table.holds:
                with self.lock:
                    overdue = self.table.release_overdue(now)
                self._publish(overdue, now)
            if now - self._last_sweep_s >= _IDLE_SWEEP_S:
                self._last_sweep_s = now
                with self.lock:
                    expired = self.table.expire_idle(now)
                self._publish(expired, now)
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
        self._publish(outcome, time.monotonic())

    def _publish(self, outcome: Outcome, now: float) -> None:
        """Publish an outcome, then send the catch-up queries it asks for."""
        self._outbox.publish(outcome, now)
        if self._request_catchup is not None:
            for request in outcome.catchups:
                self._request_catchup(self, request)

    def _process(self, batch: list[Inbound]) -> None:
        now = time.monotonic()
        decoded: list[tuple[str, str, Frame | SessionEnd]] = []
        rejections: list[Rejection] = []
        recovered: list[Inbound] = []
        for item in batch:
            if item.kind != LIVE:
                recovered.append(item)
                continue
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
        self._publish(outcome, now)
        if recovered:
            self._recover(recovered, now)
        done = time.monotonic()
        frame_latency = self._outbox.metrics.frame_latency_seconds
        for item in batch:
            if item.kind == LIVE:
                frame_latency.observe(done - item.received_s)
        self._outbox.metrics.queue_depth.set(len(self._queue))

    def _recover(self, items: list[Inbound], now: float) -> None:
        """Hand catch-up replies and ends to the table, in queue order.

        A reply is a frame the robot published before, already checked (or refused) when it
        first arrived if it did: one that does not decode is dropped without an error event.
        """
        frames: dict[tuple[str, str], list[Frame]] = {}
        for item in items:
            try:
                fleet, robot, _stream = parse_robot_key(item.key)
            except WireError:
                continue
            if item.kind == CATCHUP_DONE:
                with self.lock:
                    outcome = self.table.recover(
                        (fleet, robot), item.payload.decode(), frames.pop((fleet, robot), []), now
                    )
                    ended = self.table.catchup_done((fleet, robot), item.payload.decode(), now)
                self._publish(outcome, now)
                self._publish(ended, now)
                continue
            try:
                message = decode_inbound(item.payload, self._limits)
            except WireError:
                continue
            if isinstance(message, SessionEnd):
                continue  # ends are plain puts, never in a cache; a forged one changes nothing
            frames.setdefault((fleet, robot), []).append(message)
        for (fleet, robot), robot_frames in frames.items():
            # Replies whose query has not ended yet: fill the hold now, release at the end.
            sessions = {f.session for f in robot_frames}
            for session_id in sessions:
                with self.lock:
                    outcome = self.table.recover(
                        (fleet, robot),
                        session_id,
                        [f for f in robot_frames if f.session == session_id],
                        now,
                    )
                self._publish(outcome, now)

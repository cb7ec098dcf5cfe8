"""The receive path: the frames subscribers' channels, swept in batches into the shards.

Invariants (the why: ``docs/decisions/0006-receive-path.md``):

1. No Python runs per sample on Zenoh's threads: each subscriber's handler is a Zenoh
   ``FifoChannel``, and one thread, ``lessmap-receive``, sweeps every channel each tick and
   hands what it found to each shard in one ``Shard.offer_many``.
2. Never blocking Zenoh: the channels are as deep as a shard queue and the sweep only moves
   samples on; the bounded shard queues decide what is refused. A sample's size is checked
   before its bytes are copied.
3. Samples of a partition not owned (in flight when it moved, or during a freeze) are
   counted as foreign and dropped; those of a partition on its way here (``hold``) are kept
   aside until ``admit`` hands them on first, as probes, under the sweep's lock.
4. A take-over's probe replies (``probe``) follow every sample the channels held when they
   came, so a cache's copy never overtakes the live frames its robot put before.
"""

from __future__ import annotations

import logging
import threading
import time
import zlib
from collections import deque
from typing import TYPE_CHECKING

import zenoh

from lessmap.runtime.inbound import PROBE, Inbound
from lessmap_schemas.errors import ErrorCode

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence

    from lessmap.runtime.metrics import ServiceMetrics
    from lessmap.runtime.shard import Shard

log = logging.getLogger(__name__)

# The tick trades a few milliseconds of latency for one wake-up per sweep
# (docs/tuning/receive.md).
_TICK_S = 0.01  # sweep period while samples arrive
_IDLE_TICK_S = 0.05  # sweep period once nothing arrived for _IDLE_AFTER_S
_IDLE_AFTER_S = 1.0
_SWEEP_MAX = 8192  # samples taken from one channel per sweep: the others get their turn
_CLOSING_SWEEPS = 200  # an undeclared channel is swept this often at most, then let go
EVERY_PARTITION = -1  # the partition number ``watch`` takes for the one subscription to all
_OWNED, _FOREIGN = -1, -2  # where a partition's samples go (``_route``); else: held for it

Channel = zenoh.Handler[zenoh.Sample]


def shard_index(key: str, shards: int) -> int:
    """Return the shard of a robot's key: always the same one for a robot."""
    return zlib.crc32(key.encode()) % shards


class Receiver:
    """Sweeps the frames channels of the owned partitions into the shards."""

    def __init__(
        self,
        shards: Sequence[Shard],
        metrics: ServiceMetrics,
        *,
        max_payload_bytes: int,
        queue_depth: int,
        owned: Callable[[int], bool],
    ) -> None:
        self._shards = tuple(shards)
        self._metrics = metrics
        self._max_payload = max_payload_bytes
        self._queue_depth = queue_depth
        self._owned = owned
        # Partitions on their way here (``hold``) and what arrived for them, in order.
        self._holding: set[int] = set()
        self._held: list[tuple[int, Inbound]] = []
        # Replies of the robots' caches to a take-over's probe (``probe``), in arrival order;
        # appended on Zenoh's callback thread (a deque's append is atomic), bounded.
        self._probes: deque[Inbound] = deque(maxlen=queue_depth)
        self._channels: tuple[tuple[int, Channel], ...] = ()  # replaced whole, never mutated
        # Channels of undeclared subscribers: what they still hold is counted, then dropped.
        self._closing: list[tuple[int, Channel, int]] = []
        self._lock = threading.Lock()  # one sweep at a time (the thread's, or the last one)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lessmap-receive", daemon=True)
        self.last_sample_s = 0.0  # time.monotonic() of the last sweep that found a sample

    def channel(self) -> zenoh.handlers.FifoChannel[zenoh.Sample]:
        """Return a handler to declare a frames subscriber with."""
        return zenoh.handlers.FifoChannel(self._queue_depth)

    def watch(self, subscribers: Mapping[int, zenoh.Subscriber[Channel]]) -> None:
        """Sweep these subscribers (partition -> subscriber) from now on."""
        with self._lock:
            gone = [(p, ch, 0) for p, ch in self._channels if p not in subscribers]
            self._closing.extend(gone)
            self._channels = tuple((p, sub.handler) for p, sub in sorted(subscribers.items()))

    def hold(self, partitions: Iterable[int]) -> None:
        """Keep the samples of these partitions aside until ``admit`` (at most a queue's depth)."""
        with self._lock:
            self._holding.update(partitions)

    def probe(self, item: Inbound) -> None:
        """Queue a cache's reply to a take-over's probe (a ``PROBE`` item; callback-safe).

        The next sweep hands it on behind what the channels held when it came, so it never
        overtakes a live frame the robot put before its cache answered. A reply beyond the
        bound pushes out the oldest: a probe is a hint, the robot's next frame resumes anyway.
        """
        self._probes.append(item)

    def admit(self, partitions: Sequence[int], acquire: Callable[[int], object]) -> int:
        """Take the partitions (``acquire`` each) and hand on what was held for them.

        Under the sweep's lock: the held samples reach the shards before any live one of
        these partitions. They go as probes, so a frame the former owner had applied (it is
        in the checkpoint fetched) is dropped uncounted. Returns how many were handed on.
        """
        wanted = set(partitions)
        with self._lock:
            for p in partitions:
                acquire(p)
            self._holding -= wanted
            items = [item for p, item in self._held if p in wanted]
            self._held = [(p, item) for p, item in self._held if p not in wanted]
            self._offer(items)
        return len(items)

    def start(self) -> None:
        """Start the sweeping thread."""
        self._thread.start()

    def stop(self) -> None:
        """Stop sweeping, then sweep once more (undeclared channels keep what they hold)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self.sweep()

    def _run(self) -> None:
        tick = _TICK_S
        while not self._stop.wait(tick):
            try:
                self.sweep()
            except Exception:
                # A bug must not stop the receive path: log it, sweep again next tick.
                log.exception("receive sweep failed")
            idle = time.monotonic() - self.last_sample_s > _IDLE_AFTER_S
            tick = _IDLE_TICK_S if idle else _TICK_S

    def sweep(self) -> int:
        """Move every waiting sample to its shard; return how many were found.

        Probe replies that came before the sweep began follow the channels' samples: each
        came after the live samples its robot put before its cache answered, which are in a
        channel by then (unless a channel was cut at ``_SWEEP_MAX``: they wait a sweep).
        """
        found = 0
        with self._lock:
            probes = [self._probes.popleft() for _ in range(len(self._probes))]
            complete = True
            for partition, channel in self._channels:
                # Most channels are empty: ask once here, call ``_drain`` only for samples.
                try:
                    first = channel.try_recv()
                except zenoh.ZError:
                    continue  # undeclared (a hand-over under way): ``watch`` moves it
                if first is not None:
                    taken = self._drain(partition, channel, first)[0]
                    found += taken
                    complete = complete and taken < _SWEEP_MAX
            closing, self._closing = self._closing, []
            for partition, channel, sweeps in closing:
                taken, closed = self._drain(partition, channel)
                found += taken
                complete = complete and taken < _SWEEP_MAX
                if not closed and sweeps < _CLOSING_SWEEPS:
                    self._closing.append((partition, channel, sweeps + 1))
            if complete:
                self._offer_probes(probes)
            else:
                self._probes.extendleft(reversed(probes))  # behind the rest, next sweep
        return found

    def _offer_probes(self, probes: list[Inbound]) -> None:
        """Hand probe replies to their robots' shards; one refused is dropped quietly."""
        if not probes:
            return
        shards = self._shards
        batches: list[list[Inbound]] = [[] for _ in shards]
        for item in probes:
            batches[0 if len(shards) == 1 else shard_index(item.key, len(shards))].append(item)
        for shard, batch in zip(shards, batches, strict=True):
            if batch:
                shard.offer_many(batch)  # a full queue: the robot's next frame resumes it

    def _drain(
        self, partition: int, channel: Channel, first: zenoh.Sample | None = None
    ) -> tuple[int, bool]:
        """Take what one channel holds (after ``first``): (samples taken, channel closed)."""
        samples: list[zenoh.Sample] = [] if first is None else [first]
        closed = False
        try:
            while len(samples) < _SWEEP_MAX and (sample := channel.try_recv()) is not None:
                samples.append(sample)
        except zenoh.ZError:
            closed = True  # undeclared, and empty now
        if samples:
            self._hand_on(partition, samples)
        return len(samples), closed

    def _hand_on(self, partition: int, samples: list[zenoh.Sample]) -> None:
        now = time.monotonic()
        self.last_sample_s = now
        every = partition == EVERY_PARTITION
        if not every and not self._owned(partition):
            if partition in self._holding:
                self._keep(partition, samples, now)
                return
            # In flight when the partition moved, or during a freeze: the owner has it.
            self._metrics.frames_foreign.inc(len(samples))
            return
        limit = self._max_payload
        shards = self._shards
        batches: list[list[Inbound]] = [[] for _ in shards]
        routes: dict[str, int] = {}  # partition chunk -> where its samples go, for this batch
        foreign = held = 0
        for sample in samples:
            key = str(sample.key_expr)
            if every:
                chunk = key[key.rfind("/") + 1 :]
                route = routes.get(chunk)
                if route is None:
                    route = routes[chunk] = self._route(chunk)
                if route == _FOREIGN:
                    foreign += 1  # another instance's robot (or in flight, or frozen)
                    continue
                if route != _OWNED:
                    held += self._keep(route, [sample], now)
                    continue
            payload = sample.payload
            index = 0 if len(shards) == 1 else shard_index(key, len(shards))
            if len(payload) > limit:
                # Decided before copying the bytes: a huge sample never reaches a queue.
                detail = f"payload of {len(payload)} bytes exceeds {limit=}"
                shards[index].note_rejection(key, ErrorCode.LIMIT_EXCEEDED, detail)
                continue
            batches[index].append(Inbound(now, key, payload.to_bytes()))
        self._metrics.frames_foreign.inc(foreign)
        self._metrics.frames_received.inc(len(samples) - foreign - held)
        for shard, batch in zip(shards, batches, strict=True):
            if batch:
                self._offer_to(shard, batch)

    def _route(self, chunk: str) -> int:
        """``_OWNED``, ``_FOREIGN``, or the partition to hold the samples for."""
        try:  # any client may put here: "²", "1" * 5000, "abc" are no partition
            partition = int(chunk) if chunk.isdecimal() else None
        except ValueError:
            partition = None
        if partition is None:
            return _FOREIGN
        if self._owned(partition):
            return _OWNED
        return partition if partition in self._holding else _FOREIGN

    def _keep(self, partition: int, samples: list[zenoh.Sample], now: float) -> int:
        """Keep samples of a partition on its way here; return how many (counted received).

        Beyond the bound they are foreign, and oversized ones are dropped (the former owner
        refuses them): what is not kept the new owner may still find in the robots' caches.
        """
        room = max(0, self._queue_depth - len(self._held))
        kept = 0
        for sample in samples[:room]:
            if len(sample.payload) <= self._max_payload:
                item = Inbound(now, str(sample.key_expr), sample.payload.to_bytes(), PROBE)
                self._held.append((partition, item))
                kept += 1
        self._metrics.frames_foreign.inc(len(samples) - len(samples[:room]))
        self._metrics.frames_received.inc(kept)
        return kept

    def _offer(self, items: list[Inbound]) -> None:
        """Hand items to their robots' shards, in order."""
        shards = self._shards
        batches: list[list[Inbound]] = [[] for _ in shards]
        for item in items:
            batches[0 if len(shards) == 1 else shard_index(item.key, len(shards))].append(item)
        for shard, batch in zip(shards, batches, strict=True):
            if batch:
                self._offer_to(shard, batch)

    def _offer_to(self, shard: Shard, batch: list[Inbound]) -> None:
        for item in shard.offer_many(batch):
            if shard.stopping:
                detail = "the service is stopping; frame not taken (a restart recovers it)"
            else:
                depth = self._queue_depth
                detail = f"shard {shard.index} queue full ({depth=}); frame dropped"
            shard.note_rejection(item.key, ErrorCode.LIMIT_EXCEEDED, detail)

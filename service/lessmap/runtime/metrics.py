"""Prometheus metrics of one service instance (its own registry, so instances never mix).

The per-frame histograms are ``BatchHistogram``s: the same exposition as prometheus_client's
``Histogram`` (buckets, count, sum), but one lock and one bisection per value, and a batch of
values per call (``observe_many``), since the worker observes two latencies per frame. The
counters are ``Counter``s that skip ``inc(0)``: the outbox counts every turn's outcome, and
most of its counts are zero (prometheus' ``inc`` takes a lock and checks even for nothing).
"""

from __future__ import annotations

import math
import threading
from bisect import bisect_left
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, Counter as _PrometheusCounter, Gauge
from prometheus_client.metrics_core import HistogramMetricFamily
from prometheus_client.registry import Collector

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence


class Counter(_PrometheusCounter):
    """A prometheus_client Counter whose ``inc(0)`` returns at once (labelled children too)."""

    def inc(self, amount: float = 1, exemplar: dict[str, str] | None = None) -> None:
        """Increment by ``amount`` (>= 0); nothing to do for 0."""
        if amount or exemplar:
            super().inc(amount, exemplar)


class BatchHistogram(Collector):
    """A cumulative histogram fed one value (``observe``) or a batch (``observe_many``)."""

    def __init__(
        self,
        name: str,
        documentation: str,
        *,
        buckets: Sequence[float],
        registry: CollectorRegistry,
    ) -> None:
        bounds = sorted(float(b) for b in buckets)
        if bounds[-1] != math.inf:
            bounds.append(math.inf)
        self._name = name
        self._documentation = documentation
        self._bounds = tuple(bounds)
        self._counts = [0] * len(bounds)  # per bucket, not cumulative
        self._sum = 0.0
        self._lock = threading.Lock()
        registry.register(self)

    def observe(self, value: float) -> None:
        """Count one value (seconds) into the first bucket whose bound is >= it."""
        index = bisect_left(self._bounds, value)
        with self._lock:
            self._counts[index] += 1
            self._sum += value

    def observe_many(self, values: Sequence[float]) -> None:
        """Count a batch of values, as ``observe`` each, under one lock."""
        bounds = self._bounds
        indices = [bisect_left(bounds, value) for value in values]
        with self._lock:
            counts = self._counts
            for index in indices:
                counts[index] += 1
            total = self._sum
            for value in values:  # one by one: the same float sum as ``observe`` each
                total += value
            self._sum = total

    def collect(self) -> Iterator[HistogramMetricFamily]:
        """Yield the histogram as Prometheus reads it (cumulative buckets, sum, count)."""
        with self._lock:
            counts = list(self._counts)
            total = self._sum
        cumulative = 0
        buckets: list[tuple[str, float]] = []
        for bound, count in zip(self._bounds, counts, strict=True):
            cumulative += count
            buckets.append(("+Inf" if bound == math.inf else repr(bound), cumulative))
        yield HistogramMetricFamily(
            self._name, self._documentation, buckets=buckets, sum_value=total
        )


class ServiceMetrics:
    """Every counter, gauge and histogram ``lessmap serve`` exports on ``/metrics``."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.frames_received = Counter(
            "lessmap_frames_received", "Inbound samples on frames keys", registry=r
        )
        self.frames_applied = Counter(
            "lessmap_frames_applied", "Frames counted into a CovGraph", registry=r
        )
        self.frames_duplicate = Counter(
            "lessmap_frames_duplicate", "Frames ignored: seq already applied", registry=r
        )
        self.frames_missing = Counter(
            "lessmap_frames_missing", "Frames never received (seq gaps)", registry=r
        )
        self.frames_rejected = Counter(
            "lessmap_frames_rejected",
            "Inbound messages rejected, by reason",
            ["reason"],
            registry=r,
        )
        self.transitions = Counter(
            "lessmap_transitions", "Transitions published, by reason", ["reason"], registry=r
        )
        self.decisions = Counter("lessmap_decisions", "Spectral decisions run", registry=r)
        self.coalesced_batches = Counter(
            "lessmap_coalesced_batches", "Decisions that covered more than one frame", registry=r
        )
        self.errors_published = Counter(
            "lessmap_errors_published", "Error events published", registry=r
        )
        self.errors_suppressed = Counter(
            "lessmap_errors_suppressed", "Error events held back by the rate limit", registry=r
        )
        self.events_fenced = Counter(
            "lessmap_events_fenced",
            "Transitions, errors and states not published: the robot's partition is not owned",
            registry=r,
        )
        self.frames_foreign = Counter(
            "lessmap_frames_foreign",
            "Frames of a partition this instance does not own (left to its owner; with "
            "frames_subscription=all, every other instance's robots' frames too)",
            registry=r,
        )
        self.partitions_owned = Gauge(
            "lessmap_partitions_owned", "Partitions this instance owns", registry=r
        )
        self.partition_moves = Counter(
            "lessmap_partition_moves",
            "Partitions taken over or handed over",
            ["direction"],
            registry=r,
        )
        self.handover_release_timeouts = Counter(
            "lessmap_handover_release_timeouts",
            "Partitions taken from a live former owner without its release announcement "
            "(it did not answer within handover_release_s)",
            registry=r,
        )
        self.replies_cut = Counter(
            "lessmap_replies_cut",
            "State or area graph replies cut to the wire limits (oldest submaps, old areas)",
            ["kind"],
            registry=r,
        )
        self.checkpoints_withheld = Counter(
            "lessmap_checkpoints_withheld",
            "Checkpoints not saved: their session had a transition the fence held back",
            registry=r,
        )
        self.checkpoints_shipped = Counter(
            "lessmap_checkpoints_shipped", "Checkpoints put for the standby", registry=r
        )
        self.checkpoints_received = Counter(
            "lessmap_checkpoints_received",
            "Checkpoints taken from other instances (as standby or when taking over)",
            registry=r,
        )
        self.sessions_opened = Counter("lessmap_sessions_opened", "Sessions opened", registry=r)
        self.sessions_closed = Counter(
            "lessmap_sessions_closed", "Sessions closed, by cause", ["cause"], registry=r
        )
        self.frames_recovered = Counter(
            "lessmap_frames_recovered",
            "Frames taken from robots' publication caches after a gap (catch-up)",
            registry=r,
        )
        self.sessions_resumed = Counter(
            "lessmap_sessions_resumed", "Sessions brought back from the state store", registry=r
        )
        self.sessions_evicted = Counter(
            "lessmap_sessions_evicted", "Idle sessions moved to the state store", registry=r
        )
        self.sessions = Gauge("lessmap_sessions", "Sessions in memory", registry=r)
        self.store_durable = Gauge(
            "lessmap_store_durable",
            "1 while checkpoints reach the state store's file, 0 while durability is lost",
            registry=r,
        )
        self.store_losses = Counter(
            "lessmap_store_durability_lost",
            "Times the state store stopped taking checkpoints (write error, file lost)",
            registry=r,
        )
        self.queue_depth = Gauge(
            "lessmap_queue_depth", "Messages waiting in the shard queues", registry=r
        )
        self.decision_seconds = BatchHistogram(
            "lessmap_decision_seconds",
            "Time of one spectral decision (apply excluded)",
            buckets=(0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5),
            registry=r,
        )
        self.frame_latency_seconds = BatchHistogram(
            "lessmap_frame_latency_seconds",
            "Receipt of an inbound sample to the end of the decision covering it (published)",
            # 0.02: a camera robot's target, a median within 20 ms, reads off one bucket
            buckets=(0.001, 0.005, 0.01, 0.02, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0),
            registry=r,
        )
        self.queue_latency_seconds = BatchHistogram(
            "lessmap_queue_latency_seconds",
            "Time from receipt to processing of an inbound sample",
            buckets=(0.001, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0),
            registry=r,
        )

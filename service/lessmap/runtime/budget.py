"""Work budgets shared by the shards: edges in memory, and the admission of new sessions.

Budgets bound work, not only nodes: a frame of k features makes k(k-1)/2 pair updates and a
spectral decision costs in proportion to the CovGraph's edges (docs/BENCHMARKS.md, "Noisy
neighbours"). The session table checks a frame against three budgets before it reaches the
core (``max_pairs_per_frame``, ``max_edges_per_session`` and ``max_edges_total``, the last
one summed here over every session in memory), and asks ``SessionAdmission`` before it opens
a new session.
"""

from __future__ import annotations

import threading

from lessmap.runtime.ratelimit import RateLimiter


def pairs_of(features: int) -> int:
    """Pair updates a frame of ``features`` features can cause: k(k-1)/2."""
    return features * (features - 1) // 2


class EdgeLedger:
    """Edges held in memory, one slot per shard (each shard writes only its own slot).

    A slot holds an upper bound of its shard's edges: exact after each decision, plus the
    pairs of the frames applied since. Reading the total sums the slots without a lock: a
    value one update old only makes the check a frame more or less conservative.
    """

    def __init__(self, shards: int, max_edges_total: int) -> None:
        self.max_edges_total = max_edges_total
        self._slots = [0] * shards

    def add(self, shard: int, delta: int) -> None:
        """Change one shard's edges by ``delta`` (only that shard's worker calls it)."""
        self._slots[shard] += delta

    def total(self) -> int:
        """Edges in memory over every shard (an upper bound)."""
        return sum(self._slots)


class SessionAdmission:
    """A token bucket of new sessions per fleet, shared by the shards (thread-safe)."""

    def __init__(self, rate_per_s: float, burst: int) -> None:
        self.rate_per_s = rate_per_s
        self.burst = burst
        self._limiter = RateLimiter(rate_per_s, burst)
        self._lock = threading.Lock()

    def allow(self, fleet: str, now_s: float) -> bool:
        """Take a token for a new session of ``fleet``; False when the fleet's bucket is empty."""
        with self._lock:
            allowed, _suppressed = self._limiter.allow(fleet, now_s)
        return allowed

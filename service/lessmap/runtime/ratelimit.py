"""A token bucket per key, so one noisy robot cannot flood the error stream."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass


@dataclass(slots=True)
class _Bucket:
    tokens: float
    updated_s: float
    suppressed: int = 0


class RateLimiter:
    """Allow ``rate_per_s`` events per key with bursts of ``burst``; count what it holds back.

    The clock is passed in (``now_s``), so the limiter is deterministic under test. At most
    ``max_keys`` buckets are kept; the least recently used goes first.
    """

    def __init__(self, rate_per_s: float, burst: int, max_keys: int = 100_000) -> None:
        self._rate = rate_per_s
        self._burst = float(burst)
        self._max_keys = max_keys
        self._buckets: OrderedDict[object, _Bucket] = OrderedDict()

    def allow(self, key: object, now_s: float) -> tuple[bool, int]:
        """Take one token for ``key``.

        Returns:
            Whether the event may go out, and how many events of this key were suppressed
            since the last one that went out (reset when one goes out).
        """
        bucket = self._buckets.get(key)
        if bucket is None:
            bucket = _Bucket(tokens=self._burst, updated_s=now_s)
            self._buckets[key] = bucket
            if len(self._buckets) > self._max_keys:
                self._buckets.popitem(last=False)
        else:
            self._buckets.move_to_end(key)
            elapsed = max(0.0, now_s - bucket.updated_s)
            bucket.tokens = min(self._burst, bucket.tokens + elapsed * self._rate)
            bucket.updated_s = now_s
        if bucket.tokens >= 1.0:
            bucket.tokens -= 1.0
            suppressed, bucket.suppressed = bucket.suppressed, 0
            return True, suppressed
        bucket.suppressed += 1
        return False, bucket.suppressed

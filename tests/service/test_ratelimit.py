"""RateLimiter: a token bucket per key with a passed-in clock (deterministic, no sleeps).

Times and rates are powers of two, so the token arithmetic is exact in binary floating point.
"""

from __future__ import annotations

import pytest

from lessmap.runtime.ratelimit import RateLimiter


def drain(limiter: RateLimiter, key: object, now_s: float, count: int) -> list[tuple[bool, int]]:
    return [limiter.allow(key, now_s) for _ in range(count)]


@pytest.mark.parametrize("burst", [1, 3, 20])
def test_burst_then_refusal(burst: int) -> None:
    limiter = RateLimiter(rate_per_s=1.0, burst=burst)

    results = drain(limiter, "robot", 0.0, burst + 3)

    assert results[:burst] == [(True, 0)] * burst
    assert results[burst:] == [(False, 1), (False, 2), (False, 3)]


def test_tokens_refill_with_time_up_to_the_burst() -> None:
    limiter = RateLimiter(rate_per_s=4.0, burst=3)
    drain(limiter, "robot", 0.0, 3)

    assert limiter.allow("robot", 0.125) == (False, 1)  # half a token
    assert limiter.allow("robot", 0.25) == (True, 1)  # the second half: one token
    assert limiter.allow("robot", 0.25)[0] is False

    # A long pause refills the bucket to the burst, not beyond.
    after_pause = drain(limiter, "robot", 1000.0, 5)
    assert [allowed for allowed, _ in after_pause] == [True, True, True, False, False]


def test_suppressed_count_is_returned_once_and_reset() -> None:
    limiter = RateLimiter(rate_per_s=1.0, burst=2)
    drain(limiter, "robot", 0.0, 2)

    held_back = drain(limiter, "robot", 0.0, 4)
    assert held_back == [(False, 1), (False, 2), (False, 3), (False, 4)]

    # The next event that goes out reports the 4 suppressed since the last one ...
    assert limiter.allow("robot", 1.0) == (True, 4)
    # ... and the count starts again from zero.
    assert limiter.allow("robot", 1.0) == (False, 1)
    assert limiter.allow("robot", 2.0) == (True, 1)
    assert limiter.allow("robot", 3.0) == (True, 0)


def test_keys_are_independent() -> None:
    limiter = RateLimiter(rate_per_s=1.0, burst=2)
    drain(limiter, ("fleet", "noisy"), 0.0, 10)

    assert drain(limiter, ("fleet", "quiet"), 0.0, 2) == [(True, 0), (True, 0)]
    assert limiter.allow(("fleet", "quiet"), 0.0) == (False, 1)
    assert limiter.allow(("fleet", "noisy"), 0.0) == (False, 9)


def test_least_recently_used_key_is_forgotten() -> None:
    # A slow rate: within this test a refused key only gets tokens back if it was forgotten.
    limiter = RateLimiter(rate_per_s=2.0**-20, burst=1, max_keys=2)
    assert limiter.allow("a", 0.0) == (True, 0)
    assert limiter.allow("b", 0.0) == (True, 0)
    assert limiter.allow("a", 0.0) == (False, 1)  # touches a: b is now the oldest

    assert limiter.allow("c", 0.0) == (True, 0)  # a third key pushes b out

    assert limiter.allow("a", 0.0) == (False, 2)  # a was kept, still empty, still counting
    assert limiter.allow("b", 0.0) == (True, 0)  # b starts over with a full bucket (c goes)
    assert limiter.allow("a", 0.0) == (False, 3)
    assert limiter.allow("c", 0.0) == (True, 0)  # c was forgotten too


def test_many_keys_stay_bounded_and_recent_keys_stay_limited() -> None:
    limiter = RateLimiter(rate_per_s=2.0**-20, burst=1, max_keys=16)
    for index in range(1000):
        assert limiter.allow(index, 0.0) == (True, 0)
    # The last 16 keys are remembered (refused); older ones were forgotten (allowed again).
    assert all(limiter.allow(index, 0.0) == (False, 1) for index in range(984, 1000))
    assert limiter.allow(0, 0.0) == (True, 0)

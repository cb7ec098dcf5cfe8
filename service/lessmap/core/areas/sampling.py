"""A feature subsample that keeps covisibility: a feature is kept in every frame or in none.

A camera robot's frames carry 500-1,000+ features; a CovGraph costs their square in pairs
and its eigensolves grow with its nodes. Keeping a fixed subset of feature *ids* keeps the
kept features' counts exact, so the CovGraph seen is the full one's induced subgraph and
CovRate W_ij = a_ij / min(n_i, n_j) is unchanged on it. Rules:

1. A feature is kept when the 64-bit mix of its id (splitmix64) is under the threshold:
   the same ids in every frame, and in every robot's frames at the same threshold.
2. The threshold starts at 2**64 (keep all) and only falls, by an eighth at a time, when a
   frame would keep more than ``cap`` features: kept sets are nested, no frame keeps more
   than ``cap``, and a stream whose frames never exceed the cap is left exactly as it is.
3. The state is ``cap`` and ``threshold``, two integers a snapshot stores: a restored
   sampler keeps what the original would.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final

import numpy as np

from lessmap.core.errors import GraphError

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = ["KEEP_ALL", "FeatureSampler", "mix_ids"]

#: The threshold that keeps every feature (no 64-bit mix reaches it).
KEEP_ALL: Final = 1 << 64

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL_1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL_2 = np.uint64(0x94D049BB133111EB)


def mix_ids(ids: NDArray[np.int64]) -> NDArray[np.uint64]:
    """Return splitmix64's finalizer of each id: a bijection of 64-bit ints, uniform bits.

    A stable hash, unlike Python's salted ``hash``: the same on every run and platform.
    """
    z = ids.view(np.uint64) + _GOLDEN  # numpy arrays wrap modulo 2**64, as the mix needs
    z = (z ^ (z >> np.uint64(30))) * _MUL_1
    z = (z ^ (z >> np.uint64(27))) * _MUL_2
    return z ^ (z >> np.uint64(31))


class FeatureSampler:
    """Which features of a frame a session keeps (rules 1-3). No I/O."""

    def __init__(self, cap: int, threshold: int = KEEP_ALL) -> None:
        """Keep at most ``cap`` features a frame (0: keep all); ``threshold`` as restored.

        Raises:
            GraphError: cap is negative, or threshold is outside 0..2**64.
        """
        if cap < 0:
            msg = f"invalid feature sample cap {cap!r}: must be >= 0 (0 keeps all)"
            raise GraphError(msg)
        if not 0 <= threshold <= KEEP_ALL:
            msg = f"invalid feature sample threshold {threshold!r}: must be in 0..2**64"
            raise GraphError(msg)
        self.cap = cap
        self.threshold = threshold

    @property
    def rate(self) -> float:
        """The share of all feature ids kept (1.0 until a frame exceeded the cap)."""
        return self.threshold / KEEP_ALL

    def keep(self, features: tuple[int, ...]) -> tuple[int, ...]:
        """Return the kept features of one frame's distinct ids, in their order (rule 2).

        Raises:
            GraphError: an id is outside the int64 range.
        """
        if not self.cap or (self.threshold == KEEP_ALL and len(features) <= self.cap):
            return features
        try:
            mixed = mix_ids(np.asarray(features, dtype=np.int64))
        except OverflowError:
            msg = "feature IDs must fit in int64 to be sampled"
            raise GraphError(msg) from None
        kept = None
        if self.threshold < KEEP_ALL:
            kept = np.flatnonzero(mixed < np.uint64(self.threshold))
        count = len(features) if kept is None else kept.size
        while count > self.cap:
            self.threshold = self.threshold * 7 // 8  # integer steps: exact everywhere
            kept = np.flatnonzero(mixed < np.uint64(self.threshold))
            count = kept.size
        if kept is None:
            return features
        return tuple(features[i] for i in kept.tolist())

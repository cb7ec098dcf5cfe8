"""Sighting counts of areas: frame likelihoods (rule 5) and rate overlap (rule 6).

An area is summarised by, per feature, the number of its non-empty frames that saw it, and
its number of non-empty frames. Sums run over the counts' dicts in their order, so equal
dicts (as a restored snapshot has) give equal floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lessmap.core.errors import GraphError

if TYPE_CHECKING:
    from collections.abc import Container, Iterable

Frame = tuple[int, tuple[int, ...]]  # (seq, distinct feature IDs ascending)

_INT_ONLY = frozenset({int})  # plain ints only: bool (an int subclass) takes the slow path


@dataclass(frozen=True, slots=True)
class Profile:
    """An area's sightings as a likelihood of frames (rule 5)."""

    absent: float  # log-likelihood of a frame that sees none of the area's features
    gain: dict[int, float]  # what seeing a feature the area knows adds: log p - log(1 - p)
    unseen: float  # log p of a feature the area never saw

    def loglik(self, features: Iterable[int]) -> float:
        """Log-likelihood of one frame's distinct features."""
        total = self.absent
        for feature in features:
            total += self.gain.get(feature, self.unseen)
        return total


def profile(
    counts: dict[int, int],
    frames: int,
    leave: dict[int, int] | None = None,
    left: int = 0,
    only: Container[int] | None = None,
) -> Profile | None:
    """Return the profile of ``counts`` over ``frames`` non-empty frames.

    ``left`` of those frames, which saw ``leave``, are taken out first; None when no frame
    remains. With ``only``, the gains of other features are left out: the profile then
    gives the very same likelihood to frames of those features alone, for less work (the
    sum over every feature, ``absent``, is the same, in the same order).
    """
    remaining = frames - left
    if remaining <= 0:
        return None
    # (count + 1/2) / (frames + 1): never 0 or 1, so one odd frame is never impossible.
    denominator = remaining + 1.0
    absent = 0.0
    gain: dict[int, float] = {}
    log, log1p = math.log, math.log1p  # locals: this loop runs over an area every frame
    for feature, count in counts.items():
        seen = count - leave.get(feature, 0) if leave else count
        if seen <= 0:
            continue
        p = (seen + 0.5) / denominator
        absent_term = log1p(-p)  # the same float both sums use: computed once
        absent += absent_term
        if only is None or feature in only:
            gain[feature] = log(p) - absent_term
    return Profile(absent, gain, math.log(0.5 / denominator))


def rate_overlap(a: dict[int, int], frames_a: int, b: dict[int, int], frames_b: int) -> float:
    """Rule 6's overlap of two areas' sighting rates (0: disjoint, 1: one within the other)."""
    if frames_a <= 0 or frames_b <= 0 or not a or not b:
        return 0.0
    shared = sum(min(n / frames_b, a.get(feature, 0) / frames_a) for feature, n in b.items())
    return shared / min(sum(a.values()) / frames_a, sum(b.values()) / frames_b)


def distinct(seq: int, features: Iterable[int]) -> tuple[int, ...]:
    """Return the distinct feature IDs in ascending order, refusing non-integers."""
    values = list(features)
    if set(map(type, values)) <= _INT_ONLY:  # the common case, checked in C: every frame
        return tuple(sorted(set(values)))
    for value in values:
        # bool is an int subclass; numpy integers pass through __index__
        if isinstance(value, bool) or not hasattr(value, "__index__"):
            msg = f"frame {seq}: feature IDs must be integers, got {value!r}"
            raise GraphError(msg)
    return tuple(sorted({int(value) for value in values}))


def count(into: dict[int, int], features: Iterable[int]) -> None:
    """Add one sighting of each feature to ``into``."""
    for feature in features:
        into[feature] = into.get(feature, 0) + 1


def count_pair(first: dict[int, int], second: dict[int, int], features: Iterable[int]) -> None:
    """``count`` into two dicts in one pass (a frame's segment and its area, every frame)."""
    first_get, second_get = first.get, second.get
    for feature in features:
        first[feature] = first_get(feature, 0) + 1
        second[feature] = second_get(feature, 0) + 1


def tally(frames: Iterable[Frame]) -> tuple[dict[int, int], int]:
    """Sightings per feature, and the number of non-empty frames."""
    counts: dict[int, int] = {}
    nonempty = 0
    for _, features in frames:
        count(counts, features)
        nonempty += bool(features)
    return counts, nonempty


def without(counts: dict[int, int], taken: dict[int, int]) -> dict[int, int]:
    """``counts`` less ``taken``, features left at 0 dropped (order kept)."""
    return {
        feature: n - taken.get(feature, 0)
        for feature, n in counts.items()
        if n > taken.get(feature, 0)
    }

"""The service's Prometheus text exposition, as the fleet load benchmark reads it.

``parse_metrics`` returns every sample; ``histogram`` extracts one ``Histogram``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Histogram:
    """A Prometheus histogram: bucket upper bounds and cumulative counts."""

    bounds: tuple[float, ...]
    cumulative: tuple[float, ...]
    count: float
    total: float

    def quantile(self, q: float) -> float:
        """Upper bound of the bucket holding the q-quantile (inf past the last bound)."""
        if self.count <= 0:
            return math.nan
        for bound, seen in zip(self.bounds, self.cumulative, strict=True):
            if seen >= q * self.count:
                return bound
        return math.inf

    @property
    def mean(self) -> float:
        """Mean of the observations."""
        return self.total / self.count if self.count else math.nan


_SAMPLE = re.compile(r"^([a-zA-Z_:][\w:]*)(\{[^}]*\})?\s+(\S+)$")


def parse_metrics(text: str) -> dict[str, float]:
    """Return every sample of a Prometheus text exposition as ``name{labels}`` -> value."""
    samples: dict[str, float] = {}
    for line in text.splitlines():
        match = _SAMPLE.match(line)
        if match and not line.startswith("#"):
            samples[match[1] + (match[2] or "")] = float(match[3])
    return samples


def histogram(samples: dict[str, float], name: str) -> Histogram:
    """Extract one histogram from ``parse_metrics`` output."""
    buckets: list[tuple[float, float]] = []
    for key, value in samples.items():
        if key.startswith(f"{name}_bucket{{"):
            le = re.search(r'le="([^"]+)"', key)
            if le:
                buckets.append((float(le[1]), value))
    buckets.sort()
    return Histogram(
        tuple(b for b, _ in buckets),
        tuple(c for _, c in buckets),
        samples.get(f"{name}_count", 0.0),
        samples.get(f"{name}_sum", 0.0),
    )

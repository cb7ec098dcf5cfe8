"""The pure LESS-mapping core: CovGraph, CovRate, Shi–Malik bisection, submaps. No I/O."""

from __future__ import annotations

from lessmap.core.errors import GraphError, StaleFrameError
from lessmap.core.paper.covgraph import CovGraph, CovGraphState
from lessmap.core.paper.params import PROFILES, PartitionParams, SeedMode
from lessmap.core.paper.partitioner import Partitioner, PartitionerState
from lessmap.core.paper.spectral import Bisection, normalized_bisection, normalized_cut
from lessmap.core.paper.submaps import Evaluation, Reason, Submap, Transition

__all__ = [
    "PROFILES",
    "Bisection",
    "CovGraph",
    "CovGraphState",
    "Evaluation",
    "GraphError",
    "PartitionParams",
    "Partitioner",
    "PartitionerState",
    "Reason",
    "SeedMode",
    "StaleFrameError",
    "Submap",
    "Transition",
    "normalized_bisection",
    "normalized_cut",
]

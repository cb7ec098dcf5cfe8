"""Partitioning parameters and the paper's named threshold profiles (§3.3, Eq. 4)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Any

from lessmap.core.errors import GraphError


class SeedMode(StrEnum):
    """What the new CovGraph holds after a transition."""

    SEED = "seed"  # the new cluster's nodes, counts and internal edges (default)
    FRESH = "fresh"  # nothing: the next frame starts an empty graph


#: (Ncut_min, λ2_min) per sensor kind, as used in the paper: laser corners and stereo
#: regions in §3.3, §4.2.2 and §4.3; dense monocular FAST points in §4.2.1.
PROFILES: dict[str, tuple[float, float]] = {
    "laser": (0.25, 0.2),
    "stereo": (0.25, 0.2),
    "monocular": (0.1, 0.1),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class PartitionParams:
    """How one session's partitioner decides (the paper-faithful defaults are `laser`)."""

    ncut_min: float = 0.25  # a split is valid when Ncut <= ncut_min ...
    lambda2_min: float = 0.2  # ... and λ2 <= lambda2_min (Eq. 4; both are upper bounds)
    seed_mode: SeedMode = SeedMode.SEED
    min_frames_between: int = 0  # guard, off by default: frames after a transition with no test
    min_cluster_size: int = 1  # guard, off by default: smallest side a transition may cut off
    dense_max_nodes: int = 400  # dense counts and LAPACK up to this many nodes; CSR, ARPACK above
    history_frames: int = 2000  # frames kept to estimate the boundary frame
    keep_closed_submaps: int = 1000  # closed submaps remembered per session (oldest go)

    def __post_init__(self) -> None:
        checks = {
            "ncut_min": self.ncut_min >= 0.0,
            "lambda2_min": self.lambda2_min >= 0.0,
            "min_frames_between": self.min_frames_between >= 0,
            "min_cluster_size": self.min_cluster_size >= 1,
            "dense_max_nodes": self.dense_max_nodes >= 2,
            "history_frames": self.history_frames >= 1,
            "keep_closed_submaps": self.keep_closed_submaps >= 0,
        }
        for name, ok in checks.items():
            if not ok:
                msg = f"invalid partition parameter {name}={getattr(self, name)!r}"
                raise GraphError(msg)
        # SeedMode("x") raises ValueError with a clear message for bad strings.
        object.__setattr__(self, "seed_mode", SeedMode(self.seed_mode))

    @classmethod
    def from_profile(cls, profile: str, **overrides: Any) -> PartitionParams:
        """Return the parameters of a named profile (laser, stereo, monocular) with overrides."""
        try:
            ncut_min, lambda2_min = PROFILES[profile]
        except KeyError:
            msg = f"unknown profile {profile!r}; choose one of {', '.join(PROFILES)}"
            raise GraphError(msg) from None
        base = cls(ncut_min=ncut_min, lambda2_min=lambda2_min)
        return replace(base, **overrides)

"""The partitioning settings, defined once, mapped to ``PartitionParams``.

They are fields of the service's settings (``serve``) and flags of the offline commands
(``segment``, ``eval``, ``plot``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from lessmap.core import PROFILES, PartitionParams, SeedMode
from lessmap.errors import ConfigError
from lessmap.flags import add_flags, flag_specs, given

if TYPE_CHECKING:
    import argparse

TITLE = "partitioning (LESS-mapping Eq. 4)"


class PartitionSettings(BaseModel):
    """Thresholds and guards of the partitioner; ``ServiceSettings`` inherits these fields."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    profile: Literal["laser", "stereo", "monocular"] = Field(
        "laser",
        description="threshold profile: laser/stereo = Ncut 0.25, λ2 0.2; monocular = 0.1, 0.1",
    )
    ncut_min: float | None = Field(None, ge=0.0, description="override the profile's Ncut")
    lambda2_min: float | None = Field(None, ge=0.0, description="override the profile's λ2")
    seed_mode: SeedMode = Field(
        SeedMode.SEED,
        description="after a transition keep the new cluster in the CovGraph (seed) or start "
        "empty (fresh)",
    )
    min_frames_between: int = Field(
        0, ge=0, description="guard: frames after a transition before the next test (0 = off)"
    )
    min_cluster_size: int = Field(
        1, ge=1, description="guard: fewest features a transition may cut off (1 = off)"
    )

    def partition_params(self) -> PartitionParams:
        """Return the core's parameters: the profile's thresholds unless overridden."""
        ncut_min, lambda2_min = PROFILES[self.profile]
        return PartitionParams(
            ncut_min=self.ncut_min if self.ncut_min is not None else ncut_min,
            lambda2_min=self.lambda2_min if self.lambda2_min is not None else lambda2_min,
            seed_mode=self.seed_mode,
            min_frames_between=self.min_frames_between,
            min_cluster_size=self.min_cluster_size,
        )


def add_partition_options(parser: argparse.ArgumentParser) -> None:
    """Add the partitioning flags (the fields of ``PartitionSettings``)."""
    add_flags(parser, PartitionSettings, title=TITLE)


def partition_settings(args: argparse.Namespace) -> PartitionSettings:
    """Validate the partitioning flags that were given.

    Raises:
        ConfigError: a value is invalid (one line naming the flag).
    """
    values, origin = given(args, list(flag_specs(PartitionSettings)))
    try:
        return PartitionSettings.model_validate(values)
    except ValidationError as exc:
        error = exc.errors()[0]
        where = ".".join(str(p) for p in error["loc"])
        msg = f"invalid setting {where} = {error.get('input')!r} from flag "
        msg += f"{origin.get(where, '?')}: {error['msg']}"
        raise ConfigError(msg) from None


def partition_params(args: argparse.Namespace) -> PartitionParams:
    """Build the partition parameters from parsed options."""
    return partition_settings(args).partition_params()

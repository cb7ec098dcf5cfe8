"""The partitioning settings, defined once, mapped to ``PartitionParams``.

They are fields of the service's settings (``serve``) and flags of the offline commands
(``segment``, ``eval``, ``plot``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Final, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from lessmap.cli.flags import add_flags, flag_specs, given
from lessmap.core import PROFILES, PartitionParams, SeedMode
from lessmap.core.areas.tracker import AreaParams
from lessmap.core.segmenter import DEFAULT_METHOD as _DEFAULT_METHOD
from lessmap.errors import setting_error

if TYPE_CHECKING:
    import argparse

TITLE = "partitioning (LESS-mapping Eq. 4)"

#: The segmentation methods: ``paper`` is LESS-mapping as published; ``areas`` is
#: ``lessmap.core.areas.tracker`` (pooled evidence, confirmed splits, named revisits; the
#: default); ``rooms`` is ``lessmap.core.rooms.tracker`` (a windowed cut, areas named).
METHODS = ("paper", "areas", "rooms")
#: The default method's name, for the offline commands and ``lessmap serve``.
DEFAULT_METHOD: Final = _DEFAULT_METHOD.value


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
    # The areas method's AreaParams.max_features_kept: a camera's frames of 1,000 features
    # are decided at camera rate on a fixed subsample of ids (lessmap.core.areas.sampling).
    max_features_kept: int = Field(
        AreaParams().max_features_kept,
        ge=0,
        description="areas: features a frame keeps at most, the same ids in every frame "
        "(a subsample by id hash; a stream under it is taken whole; 0 = keep all)",
    )

    # The areas method's AreaParams.spans_in_views: its spans of rules 3a and 3c measured in
    # the stream's own view changes, so a robot's frame rate does not change what they mean.
    spans_in_views: bool = Field(
        AreaParams().spans_in_views,
        description="areas: the confirmation spans grow with the stream's view changes "
        "(learnt from its frames), so a robot sending many frames a metre gets as many "
        "metres; never fewer frames than measured; false: in frames",
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
        raise setting_error(msg, error["type"], from_flag=True) from None


def partition_params(args: argparse.Namespace) -> PartitionParams:
    """Build the partition parameters from parsed options."""
    return partition_settings(args).partition_params()


def add_method_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--method`` (default ``areas``, as ``serve``'s) and ``--empty-frames-omitted``."""
    parser.add_argument(
        "--method",
        choices=METHODS,
        default=DEFAULT_METHOD,
        help="areas (default): pooled evidence, confirmed splits of at least 5 features, "
        "revisits named (the proposer's thresholds are Ncut 0.4, λ2 0.4 unless "
        "--ncut-min/--lambda2-min are given); rooms: a windowed cut of the recent frames "
        "sized by how fast the view changes, for buildings (finds small rooms and wide "
        "openings, decides at the door); paper: LESS-mapping as published",
    )
    parser.add_argument(
        "--empty-frames-omitted",
        action="store_true",
        help="the file's frames leave out the empty ones (a frame only when something is "
        "seen, as MRCLAM's): with --method areas a gap between stamps then counts as the "
        "empty frames it left out, i.e. blindness (by default stamps are not read)",
    )


def area_params(settings: PartitionSettings, *, empty_frames_omitted: bool = False) -> AreaParams:
    """Return the area tracker's parameters: its own proposer thresholds unless overridden.

    The profile is not applied: the proposer answers before the paper's thresholds would.
    The guards and the seed mode pass through to the proposer; ``max_features_kept`` and
    ``spans_in_views`` to the tracker. A stream that leaves out its empty frames has its
    stamp gaps read as blindness (``AreaParams.for_stream``).
    """
    base = AreaParams().for_stream(empty_frames_omitted=empty_frames_omitted)
    proposal = replace(
        base.proposal,
        ncut_min=settings.ncut_min if settings.ncut_min is not None else base.proposal.ncut_min,
        lambda2_min=settings.lambda2_min
        if settings.lambda2_min is not None
        else base.proposal.lambda2_min,
        seed_mode=settings.seed_mode,
        min_frames_between=settings.min_frames_between,
        min_cluster_size=settings.min_cluster_size,
    )
    return replace(
        base,
        proposal=proposal,
        max_features_kept=settings.max_features_kept,
        spans_in_views=settings.spans_in_views,
    )

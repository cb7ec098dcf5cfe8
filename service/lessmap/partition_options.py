"""The partitioning options every command shares (segment, eval, plot): one definition."""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.core import PROFILES, PartitionParams, SeedMode

if TYPE_CHECKING:
    import argparse


def add_partition_options(parser: argparse.ArgumentParser) -> None:
    """Add the partitioning options shared by offline and online commands."""
    group = parser.add_argument_group("partitioning (LESS-mapping Eq. 4)")
    group.add_argument(
        "--profile",
        choices=sorted(PROFILES),
        default="laser",
        help="threshold profile: laser/stereo = Ncut 0.25, λ2 0.2; monocular = 0.1, 0.1 "
        "(default: laser)",
    )
    group.add_argument("--ncut-min", type=float, help="override the profile's Ncut threshold")
    group.add_argument("--lambda2-min", type=float, help="override the profile's λ2 threshold")
    group.add_argument(
        "--seed-mode",
        choices=[m.value for m in SeedMode],
        default=SeedMode.SEED.value,
        help="after a transition keep the new cluster in the CovGraph (seed) or start empty "
        "(fresh); default: seed",
    )
    group.add_argument(
        "--min-frames-between",
        type=int,
        default=0,
        help="guard: frames after a transition before the next test (default 0: off)",
    )
    group.add_argument(
        "--min-cluster-size",
        type=int,
        default=1,
        help="guard: smallest number of features a transition may cut off (default 1: off)",
    )


def partition_params(args: argparse.Namespace) -> PartitionParams:
    """Build the partition parameters from parsed options."""
    overrides: dict[str, object] = {
        "seed_mode": SeedMode(args.seed_mode),
        "min_frames_between": args.min_frames_between,
        "min_cluster_size": args.min_cluster_size,
    }
    if args.ncut_min is not None:
        overrides["ncut_min"] = args.ncut_min
    if args.lambda2_min is not None:
        overrides["lambda2_min"] = args.lambda2_min
    return PartitionParams.from_profile(args.profile, **overrides)

"""``lessmap sim --floorplan MAP``: robots touring a real floor plan (options and run).

``lessmap.sim.command`` owns the command; this module adds the floor-plan options and runs
the simulation when ``--floorplan`` is given. Every bad input is one line on stderr. The
options need the standard library only: ``lessmap sim --help`` loads no numpy or scipy.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap.floorplan.options import PROFILES, FloorplanOptions, TourOptions

if TYPE_CHECKING:
    import argparse

__all__ = ["DEFAULT_ROBOTS", "add_floorplan_arguments", "simulate_floorplan_files"]

DEFAULT_ROBOTS = 2
DEFAULTS = FloorplanOptions()


def add_floorplan_arguments(sim: argparse.ArgumentParser) -> None:
    """Add the ``--floorplan`` options of ``lessmap sim``."""
    group = sim.add_argument_group(
        "floor plan",
        "Tour a real occupancy grid instead: every room, collision-free, with ground truth "
        "from a labelled image. --out writes <name>.frames.jsonl, <name>.truth.jsonl and "
        "<name>.floorplan.json. Also uses --robots (default: 2), --seed, --out, --name "
        "(default: the map's name) and --publish.",
    )
    group.add_argument(
        "--floorplan",
        type=Path,
        metavar="MAP",
        help="map image (PNG, PGM; grey >= 250 is free) or a ROS map_server YAML",
    )
    group.add_argument(
        "--resolution",
        type=float,
        metavar="M",
        help="metres a pixel of a map image (default: 0.05; a YAML gives its own)",
    )
    group.add_argument(
        "--labels",
        type=Path,
        metavar="GT.png",
        help="ground-truth rooms: the map with a black line across every door "
        "(without it, tours cover 4 m squares and every frame's room is 0)",
    )
    group.add_argument(
        "--sensor",
        choices=list(PROFILES),
        default=DEFAULTS.sensor.name,
        help="laser270/laser360: 8 m, a landmark every 0.5 m of wall; sparse: corners and a "
        "point every 2.5 m, 360°; camera: 90°, 7 m, wall texture, hundreds a frame "
        "(default: %(default)s)",
    )
    group.add_argument(
        "--rate",
        type=float,
        default=DEFAULTS.tour.rate_hz,
        metavar="HZ",
        help="frames a second; stamps are seq / rate (default: %(default)s)",
    )
    group.add_argument(
        "--speed-m",
        type=float,
        default=DEFAULTS.tour.speed_m_per_frame,
        metavar="M_PER_FRAME",
        help="metres walked a frame (default: %(default)s)",
    )
    group.add_argument(
        "--robot-radius",
        type=float,
        default=DEFAULTS.robot_radius_m,
        metavar="M",
        help="clearance kept from walls; narrower doors are squeezed through "
        "(default: %(default)s)",
    )
    group.add_argument(
        "--max-frames",
        type=int,
        metavar="N",
        help="stop each robot after N frames (default: when it has visited every room)",
    )


def simulate_floorplan_files(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Run the floor-plan simulation of ``args``; write its files with ``--out``.

    Returns:
        The frames-file rows, robots interleaved by stamp (for ``--publish``).

    Raises:
        ConfigError: a bad option or file (missing, not an image, no free cell, no room
            reachable, ...); the message names it.
    """
    from lessmap.errors import ConfigError
    from lessmap.floorplan.grid import FloorplanError

    try:
        return _simulate(args)
    except FloorplanError as exc:
        raise ConfigError(str(exc)) from None


def _simulate(args: argparse.Namespace) -> list[dict[str, Any]]:
    from lessmap.cli.progress import progress
    from lessmap.floorplan.grid import FloorplanError, load_grid, room_labels
    from lessmap.floorplan.runfiles import write_floorplan_run
    from lessmap.floorplan.simulation import simulate_floorplan

    started = time.monotonic()

    def say(text: str) -> None:
        sys.stderr.write(f"lessmap sim: {time.monotonic() - started:5.1f} s  {text}\n")

    options = FloorplanOptions(
        sensor=PROFILES[args.sensor],
        robots=DEFAULT_ROBOTS if args.robots is None else args.robots,
        seed=args.seed,
        robot_radius_m=args.robot_radius,
        tour=TourOptions(
            speed_m_per_frame=args.speed_m, rate_hz=args.rate, max_frames=args.max_frames
        ),
        block_m=DEFAULTS.block_m,
    )
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        msg = f"{args.out}: --out must be a folder, this is a file"
        raise FloorplanError(msg)
    if args.resolution is not None and not args.resolution > 0:
        msg = f"--resolution must be above 0 m a pixel, got {args.resolution}"
        raise FloorplanError(msg)
    grid = load_grid(args.floorplan, args.resolution)
    labels = None if args.labels is None else room_labels(args.labels, grid.resolution_m)
    with progress(args) as shown:
        run = simulate_floorplan(grid, labels, options, progress=say, steps=shown)
    frames = len(run.frames)
    mean = sum(len(f["features"]) for f in run.frames) / max(1, frames)
    walked = sum(run.path_m.values())
    per_100 = 100.0 * len(run.room_changes) / walked if walked else 0.0
    say(
        f"{frames} frames, {mean:.1f} features a frame, {walked:.0f} m walked, "
        f"{len(run.rooms_visited)} {'rooms' if run.rooms else 'squares'} visited, "
        f"{len(run.rooms_skipped)} unreachable, "
        f"{len(run.room_changes)} room changes ({per_100:.1f} per 100 m)"
    )
    if args.out:
        name = args.name or args.floorplan.stem
        sources = {
            "map": str(args.floorplan),
            "labels": None if args.labels is None else str(args.labels),
        }
        paths = write_floorplan_run(run, grid, args.out, name, sources)
        sys.stdout.write(json.dumps({k: str(v) for k, v in paths._asdict().items()}) + "\n")
    return run.frames

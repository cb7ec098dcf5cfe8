"""``lessmap sim``: a seeded building or a real floor plan, written to files or published live.

The generated building is ``lessmap.sim``; ``--floorplan MAP`` tours a real occupancy grid
instead (``lessmap.floorplan``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap.floorplan.sim_command import add_floorplan_arguments, simulate_floorplan_files
from lessmap.sim.simulator import simulate, write_run
from lessmap_client.cli_options import (
    add_zenoh_options,
    float_up_to,
    positive_float,
    positive_int,
    zenoh_options,
)

if TYPE_CHECKING:
    from lessmap_client.cli_options import ZenohOptions


def configure(sim: argparse.ArgumentParser) -> None:
    """Define ``lessmap sim``."""
    sim.description = (
        "A seeded simulated building (rooms, doors, wall landmarks, a 270° "
        "range- and wall-limited laser) walked by robots. --out writes <name>.frames.jsonl, "
        "<name>.truth.jsonl and <name>.building.json; --publish streams the frames live. "
        "With --floorplan MAP, robots tour a real floor plan instead (options below)."
    )
    sim.add_argument("--seed", type=int, default=0, help="seeds everything")
    sim.add_argument("--rooms", type=positive_int, default=8, help="rooms of the building")
    sim.add_argument("--robots", type=positive_int, help="robots (default: 3; 2 with --floorplan)")
    sim.add_argument("--frames", type=positive_int, default=600, help="frames per robot (2 Hz)")
    sim.add_argument(
        "--fov",
        type=float_up_to(360.0),
        default=None,
        help="sensor field of view, degrees (default: 270)",
    )
    sim.add_argument("-o", "--out", type=Path, metavar="DIR", help="write the run to this folder")
    sim.add_argument(
        "--name", help="file name stem (default: sim; the map's name with --floorplan)"
    )
    sim.add_argument("--publish", action="store_true", help="publish the frames live")
    sim.add_argument("--fleet", default="sim", help="fleet of the published robots")
    sim.add_argument(
        "--speed", type=positive_float, default=1.0, help="playback rate with --publish"
    )
    add_zenoh_options(sim)
    add_floorplan_arguments(sim)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap sim``."""
    if not args.out and not args.publish:
        sys.stderr.write("lessmap sim: nothing to do; give --out DIR and/or --publish\n")
        return 1
    net = zenoh_options(args)
    if args.floorplan is not None:
        frames = simulate_floorplan_files(args)
    else:
        options = {} if args.fov is None else {"fov_deg": args.fov}
        robots = 3 if args.robots is None else args.robots
        run = simulate(
            args.seed, rooms=args.rooms, robots=robots, frames_per_robot=args.frames, **options
        )
        if args.out:
            paths = write_run(run, args.out, args.name or "sim")
            sys.stdout.write(json.dumps({k: str(v) for k, v in paths._asdict().items()}) + "\n")
        frames = run.frames
    if args.publish:
        _publish(frames, args, net)
    return 0


def _publish(rows: list[dict[str, Any]], args: argparse.Namespace, net: ZenohOptions) -> None:
    from lessmap.cli.progress import polled, progress
    from lessmap_client.adapters.replay import RecordedFrame, ReplayStats, replay

    frames = [
        RecordedFrame(
            f["robot"],
            f["seq"],
            f["stamp"],
            f["features"],
            tuple(f["pose"]) if f["pose"] else None,
        )
        for f in rows
    ]
    stats = ReplayStats()
    with (
        net.open_session() as session,
        progress(args) as shown,
        polled(shown, f"publishing to fleet {args.fleet}", len(frames), lambda: stats.frames),
    ):
        # Each robot's first frame waits for its partition's owner, as replay's does.
        replay(
            frames,
            session,
            args.fleet,
            speed=args.speed,
            wait_service_s=net.connect_timeout_s,
            stats=stats,
        )
    sys.stdout.write(json.dumps({"published": stats.frames, "robots": stats.robots}) + "\n")

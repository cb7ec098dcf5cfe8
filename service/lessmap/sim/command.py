"""``lessmap sim``: a seeded building or a real floor plan, written to files or published live.

The generated building is ``lessmap.sim``; ``--floorplan MAP`` tours a real occupancy grid
instead (``lessmap.floorplan``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from lessmap.floorplan.sim_command import add_floorplan_arguments, simulate_floorplan_files
from lessmap.sim.simulator import simulate, write_run
from lessmap_client.cli_client import add_zenoh_options, endpoints


def configure(sim: argparse.ArgumentParser) -> None:
    """Define ``lessmap sim``."""
    sim.description = (
        "A seeded simulated building (rooms, doors, wall landmarks, a 270° "
        "range- and wall-limited laser) walked by robots. --out writes <name>.frames.jsonl, "
        "<name>.truth.jsonl and <name>.building.json; --publish streams the frames live. "
        "With --floorplan MAP, robots tour a real floor plan instead (options below)."
    )
    sim.add_argument("--seed", type=int, default=0, help="seeds everything (default: 0)")
    sim.add_argument("--rooms", type=int, default=8)
    sim.add_argument("--robots", type=int, help="robots (default: 3; 2 with --floorplan)")
    sim.add_argument("--frames", type=int, default=600, help="frames per robot (2 Hz)")
    sim.add_argument("--fov", type=float, default=None, help="sensor field of view, degrees")
    sim.add_argument("--out", type=Path, help="write the run to this folder")
    sim.add_argument(
        "--name", help="file name stem (default: sim; the map's name with --floorplan)"
    )
    sim.add_argument("--publish", action="store_true", help="publish the frames live")
    sim.add_argument("--fleet", default="sim")
    sim.add_argument("--speed", type=float, default=1.0, help="playback rate with --publish")
    add_zenoh_options(sim)
    add_floorplan_arguments(sim)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap sim``."""
    if not args.out and not args.publish:
        sys.stderr.write("lessmap sim: nothing to do; give --out DIR and/or --publish\n")
        return 1
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
        _publish(frames, args)
    return 0


def _publish(rows: list[dict[str, Any]], args: argparse.Namespace) -> None:
    from lessmap_client.adapters.replay import RecordedFrame, replay
    from lessmap_client.session import open_session

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
    with open_session(endpoints(args), args.mode) as session:
        stats = replay(frames, session, args.fleet, speed=args.speed)
    sys.stdout.write(json.dumps({"published": stats.frames, "robots": stats.robots}) + "\n")

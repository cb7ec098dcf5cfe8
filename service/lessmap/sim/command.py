"""``lessmap sim``: the seeded simulated building, written to files or published live."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lessmap.sim.simulator import simulate, write_run
from lessmap_client.cli_options import (
    add_zenoh_options,
    float_up_to,
    positive_float,
    positive_int,
    zenoh_options,
)


def configure(sim: argparse.ArgumentParser) -> None:
    """Define ``lessmap sim``."""
    sim.description = (
        "A seeded simulated building (rooms, doors, wall landmarks, a 270° "
        "range- and wall-limited laser) walked by robots. --out writes <name>.frames.jsonl, "
        "<name>.truth.jsonl and <name>.building.json; --publish streams the frames live."
    )
    sim.add_argument("--seed", type=int, default=0, help="building, routes and sensors seed")
    sim.add_argument("--rooms", type=positive_int, default=8, help="rooms of the building")
    sim.add_argument("--robots", type=positive_int, default=3, help="robots")
    sim.add_argument("--frames", type=positive_int, default=600, help="frames per robot (2 Hz)")
    sim.add_argument(
        "--fov",
        type=float_up_to(360.0),
        default=None,
        help="sensor field of view, degrees (default: 270)",
    )
    sim.add_argument("-o", "--out", type=Path, metavar="DIR", help="write the run to this folder")
    sim.add_argument("--name", default="sim", help="file name stem")
    sim.add_argument("--publish", action="store_true", help="publish the frames live")
    sim.add_argument("--fleet", default="sim", help="fleet of the published robots")
    sim.add_argument(
        "--speed", type=positive_float, default=1.0, help="playback rate with --publish"
    )
    add_zenoh_options(sim)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap sim``."""
    from lessmap_client.adapters.replay import RecordedFrame, replay

    if not args.out and not args.publish:
        sys.stderr.write("lessmap sim: nothing to do; give --out DIR and/or --publish\n")
        return 1
    net = zenoh_options(args)
    options = {} if args.fov is None else {"fov_deg": args.fov}
    run = simulate(
        args.seed, rooms=args.rooms, robots=args.robots, frames_per_robot=args.frames, **options
    )
    if args.out:
        paths = write_run(run, args.out, args.name)
        sys.stdout.write(json.dumps({k: str(v) for k, v in paths._asdict().items()}) + "\n")
    if args.publish:
        frames = [
            RecordedFrame(
                f["robot"],
                f["seq"],
                f["stamp"],
                f["features"],
                tuple(f["pose"]) if f["pose"] else None,
            )
            for f in run.frames
        ]
        with net.open_session() as session:
            # Each robot's first frame waits for its partition's owner, as replay's does.
            stats = replay(
                frames, session, args.fleet, speed=args.speed, wait_service_s=net.connect_timeout_s
            )
        sys.stdout.write(json.dumps({"published": stats.frames, "robots": stats.robots}) + "\n")
    return 0

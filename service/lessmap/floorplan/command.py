"""``lessmap rooms``: a room map from a frames file with poses or a running fleet, as map files.

A file is segmented (or its ``lessmap segment`` output read) and mapped once; a fleet
(``--fleet``) is followed on the bus by ``follow`` and its map redrawn as it walks.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap.cli.foreground import add_run_options
from lessmap_client.cli_options import add_zenoh_options, non_negative_int, positive_float

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable

    import numpy as np
    from numpy.typing import NDArray

    from lessmap.floorplan.grid import OccupancyGrid
    from lessmap.floorplan.live import LiveTrajectories
    from lessmap.floorplan.roommap import PassageRegions, RoomMapParams


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap rooms``."""
    parser.description = (
        "Segment FRAMES (or read a lessmap segment output), then label every free cell of MAP "
        "the robots walked with its area: a cell takes the area of the geodesically nearest "
        "pose, a region between doorways mostly one area's is given to it whole, and a room "
        "never crosses a doorway. Writes "
        "OUT.pgm + OUT.yaml (map_server: grey = room 1..254, 0 free without a room, 255 "
        "occupied; negate 1) and OUT.png (colours); prints one JSON line. Poses must be in "
        "the map's frame (an image's bottom-left corner is (0, 0) unless a YAML says otherwise). "
        "With --fleet F instead of FRAMES, follows a running fleet: its robots' poses from "
        "their frames and the service's transitions, the files rewritten every --every "
        "seconds while the map changes and once more at the end (--duration, SIGINT or "
        "SIGTERM), a JSON line each time."
    )
    parser.add_argument(
        "frames", metavar="FRAMES", type=Path, nargs="?", help="frames file with poses"
    )
    parser.add_argument(
        "--map", required=True, type=Path, help="occupancy map: an image or a map_server YAML"
    )
    parser.add_argument(
        "--resolution",
        type=float,
        default=None,
        help="metres per pixel of an image map (default 0.05; a YAML names its own)",
    )
    parser.add_argument(
        "--method",
        choices=("areas", "rooms", "paper"),
        default=None,
        help="segmentation method of FRAMES when no --transitions are given (default areas)",
    )
    parser.add_argument(
        "--transitions",
        type=Path,
        metavar="T.jsonl",
        help="use this lessmap segment output instead of segmenting FRAMES",
    )
    parser.add_argument(
        "--robot",
        action="append",
        help="only this robot (repeatable; default: every robot, areas merged where they overlap)",
    )
    parser.add_argument(
        "--labels", type=Path, metavar="GT.png", help="ground-truth rooms: print P/R"
    )
    parser.add_argument("-o", "--out", required=True, type=Path, metavar="OUT_STEM")
    add_room_map_options(parser)
    live = parser.add_argument_group("a running fleet (instead of FRAMES)")
    live.add_argument("--fleet", help="follow this fleet on the bus")
    live.add_argument(
        "--every",
        type=positive_float,
        default=10.0,
        metavar="S",
        help="redraw the map at most this often while it changes (default %(default)s)",
    )
    live.add_argument(
        "--history",
        type=non_negative_int,
        default=1000,
        metavar="N",
        help="on joining, fetch up to N recent frames of each robot from its publication "
        "cache (0: live frames only; default %(default)s)",
    )
    add_run_options(parser)
    add_zenoh_options(parser)


def add_room_map_options(parser: argparse.ArgumentParser) -> None:
    """The room-map rules' options, shared with the floor-plan benchmark."""
    from lessmap.floorplan.roommap import RoomMapParams

    defaults = RoomMapParams()
    parser.add_argument(
        "--max-distance-m",
        type=float,
        default=defaults.max_distance_m,
        help="cells farther than this walk from every pose stay unlabelled (default %(default)s)",
    )
    parser.add_argument(
        "--door-width-m",
        type=float,
        default=defaults.door_width_m,
        help="passages narrower than this bound rooms (rules 3, 5); 0: off (default %(default)s)",
    )
    parser.add_argument(
        "--furniture-max-m",
        type=float,
        default=defaults.furniture_max_m,
        help=(
            "an obstacle joined to no wall and at most this long is furniture, never a "
            "doorway's side (rules 3, 5); 0: off (default %(default)s)"
        ),
    )
    parser.add_argument(
        "--room-opening-m",
        type=float,
        default=defaults.room_opening_m,
        help=(
            "a room also stops at openings narrower than this where the part beyond holds "
            "--min-room-m2 (rule 5); 0: at doorways only (default %(default)s)"
        ),
    )
    parser.add_argument(
        "--min-room-m2",
        type=float,
        default=defaults.min_room_m2,
        help="the smallest part beyond an opening that is a room (default %(default)s)",
    )
    parser.add_argument(
        "--keep-shared-regions",
        action="store_true",
        help=(
            "cells of a doorway region no area holds and no wider passage cuts keep the "
            "nearest pose's area instead of going to the region's largest area (rule 3)"
        ),
    )
    parser.add_argument(
        "--no-furniture-rooms",
        action="store_true",
        help="leave furniture unlabelled instead of giving it the room around it (rule 6)",
    )
    parser.add_argument(
        "--join-across-doorways",
        action="store_true",
        help=(
            "an area's room may span doorway regions (rule 5 off): for maps whose "
            "furniture narrows rooms below a door's width"
        ),
    )


def room_map_params(args: argparse.Namespace) -> RoomMapParams:
    """The ``RoomMapParams`` of ``add_room_map_options``; ValueError when out of range."""
    from lessmap.floorplan.roommap import RoomMapParams

    return RoomMapParams(
        max_distance_m=args.max_distance_m,
        door_width_m=args.door_width_m,
        furniture_max_m=args.furniture_max_m,
        room_opening_m=args.room_opening_m,
        min_room_m2=args.min_room_m2,
        split_at_doorways=not args.join_across_doorways,
        furniture_rooms=not args.no_furniture_rooms,
        region_plurality=not args.keep_shared_regions,
    )


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap rooms``."""
    from threadpoolctl import threadpool_limits

    from lessmap.cli.foreground import stop_signals
    from lessmap.cli.progress import progress
    from lessmap.errors import ConfigError
    from lessmap.floorplan.grid import FloorplanError, load_grid, room_labels
    from lessmap.floorplan.roommap import passage_regions

    # Signals first: one during start-up still ends cleanly. BLAS on one thread, as serve
    # and segment run it: OpenBLAS threads fighting over a busy host's cores cost the small
    # factorizations of the segmentation many times their work.
    with stop_signals() as stop, threadpool_limits(limits=1):
        if (args.frames is None) == (args.fleet is None):
            msg = "give FRAMES (a file) or --fleet F (a running fleet), one of them"
            raise ConfigError(msg)
        if args.fleet is not None and (
            args.transitions is not None or args.method is not None or "*" in args.fleet
        ):
            msg = (
                "--fleet names one fleet and uses the service's transitions "
                "(no --transitions, no --method: the service's method applies)"
            )
            raise ConfigError(msg)
        if args.fleet is None and args.duration is not None:
            msg = "--duration bounds how long --fleet follows a fleet; a file has no duration"
            raise ConfigError(msg)
        if args.out.name == "" or not args.out.resolve().parent.is_dir():
            msg = f"-o {args.out}: no folder {args.out.parent}"
            raise ConfigError(msg)
        try:
            params = room_map_params(args)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        with progress(args) as shown:
            shown.stage(f"reading {args.map.name}")
            grid = load_grid(args.map, args.resolution)
            truth = None
            if args.labels is not None:
                truth = room_labels(args.labels, grid.resolution_m, min_room_m2=0.0)
                if truth.shape != grid.shape:
                    msg = f"--labels {args.labels}: {truth.shape} pixels, the map has {grid.shape}"
                    raise FloorplanError(msg)
            shown.stage("finding the map's doorways")
            regions = passage_regions(grid, params)
            if args.fleet is None:
                return _from_file(args, grid, params, regions, truth, shown.stage)
        from lessmap.floorplan.follow import follow_fleet

        def draw(trajectories: LiveTrajectories) -> dict[str, Any] | None:
            return _draw_live(args, grid, params, regions, truth, trajectories)

        return follow_fleet(args, stop, draw)


def _from_file(
    args: argparse.Namespace,
    grid: OccupancyGrid,
    params: RoomMapParams,
    regions: PassageRegions | None,
    truth: NDArray[np.int32] | None,
    stage: Callable[[str], None],
) -> int:
    """The room map of a frames file, segmented here or by a ``lessmap segment`` output."""
    from lessmap.files.frames import read_frames
    from lessmap.floorplan.grid import FloorplanError
    from lessmap.floorplan.streams import (
        frame_areas,
        method_cuts,
        read_poses,
        read_transitions,
    )

    stage(f"reading {args.frames.name}")
    frames = list(read_frames(args.frames))
    if args.robot:
        frames = [f for f in frames if f.robot in set(args.robot)]
    if not frames:
        which = f" of robot {', '.join(args.robot)}" if args.robot else ""
        msg = f"{args.frames}: no frames{which}"
        raise FloorplanError(msg)
    poses = read_poses(frames, str(args.frames))
    if args.transitions is not None:
        cuts = read_transitions(args.transitions)
        source = str(args.transitions)
    else:
        method = args.method or "areas"  # its room maps score highest (docs/ROOMMAPS.md)
        stage(f"segmenting ({method})")
        cuts = method_cuts(frames, method)
        source = method
    robots = [(p.xy, frame_areas(p.seqs, cuts.get(robot, [])) + 1) for robot, p in poses.items()]
    stage("labelling the map" + (" and scoring it" if truth is not None else ""))
    record: dict[str, Any] = {
        "robots": sorted(poses),
        "segmentation": source,
        "transitions": sum(len(cuts.get(robot, [])) for robot in poses),
    }
    record.update(_room_map_files(args, grid, params, regions, truth, robots, str(args.frames)))
    sys.stdout.write(json.dumps(record) + "\n")
    return 0


def _draw_live(
    args: argparse.Namespace,
    grid: OccupancyGrid,
    params: RoomMapParams,
    regions: PassageRegions | None,
    truth: NDArray[np.int32] | None,
    trajectories: LiveTrajectories,
) -> dict[str, Any] | None:
    """The room map of what a fleet's robots walked so far, written; None before any pose."""
    wanted = set(args.robot or ())
    tracks = [t for t in trajectories.tracks() if not wanted or t.robot in wanted]
    if not tracks:
        return None
    record: dict[str, Any] = {
        "fleet": args.fleet,
        "robots": sorted({t.robot for t in tracks}),
        "sessions": len(tracks),
        "poses": sum(t.seqs.size for t in tracks),
        "segmentation": "service",
    }
    robots = [(t.xy, t.areas + 1) for t in tracks]
    record.update(
        _room_map_files(args, grid, params, regions, truth, robots, f"fleet {args.fleet}")
    )
    return record


def _room_map_files(
    args: argparse.Namespace,
    grid: OccupancyGrid,
    params: RoomMapParams,
    regions: PassageRegions | None,
    truth: NDArray[np.int32] | None,
    robots: list[tuple[NDArray[np.float64], NDArray[np.int64]]],
    source: str,
) -> dict[str, Any]:
    """Draw the robots' room map and write its files; their names, rooms and score.

    Raises:
        FloorplanError: no pose lies on a free cell of the map.
    """
    import numpy as np

    from lessmap.floorplan.grid import FloorplanError
    from lessmap.floorplan.mapfile import write_room_map
    from lessmap.floorplan.metric import precision_recall
    from lessmap.floorplan.roommap import fleet_room_map

    rooms = fleet_room_map(grid, robots, params, regions)
    if not rooms.any():
        msg = (
            f"{source}: no pose lies on a free cell of {args.map} "
            "(are the poses in the map's frame and metres?)"
        )
        raise FloorplanError(msg)
    files = write_room_map(rooms, grid, args.out)
    record: dict[str, Any] = {
        "rooms": len(np.unique(rooms[rooms > 0])),
        "labelled_share": round(float((rooms[grid.free] > 0).sum() / grid.free.sum()), 4),
        "files": {
            "pgm": str(files.pgm),
            "yaml": str(files.yaml),
            "png": str(files.png),
            "rooms": str(files.rooms),
        },
    }
    if truth is not None:
        score = precision_recall(rooms, truth)
        record["benchmark"] = {
            "precision": _rounded(score.precision),
            "recall": _rounded(score.recall),
            "precision_pixels": _rounded(score.precision_pixels),
            "recall_pixels": _rounded(score.recall_pixels),
            "rooms": score.rooms,
            "segments": score.segments,
        }
    return record


def _rounded(value: float) -> float | None:
    return None if math.isnan(value) else round(value, 4)

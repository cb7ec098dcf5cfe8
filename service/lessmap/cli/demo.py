"""``lessmap demo``: the service, a simulated fleet and the live view, in one command.

It runs exactly what a deployment runs, in one process: the service on its embedded
router (``tcp/127.0.0.1:7447``), one ``RobotPublisher`` per simulated robot streaming the
sim's frames over Zenoh, and a ``FleetClient`` feeding the watch view. At the end every
robot ends its session, the final states are read back over Zenoh, and the transitions are
scored against the simulator's ground truth.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from lessmap.config.settings import EMBEDDED_ENDPOINT, load_settings
from lessmap_client.cli_options import (
    add_zenoh_options,
    positive_float,
    positive_int,
)

if TYPE_CHECKING:
    from lessmap.sim.simulator import SimRun
    from lessmap_schemas.messages import Transition

_RATE_HZ = 2.0  # the simulated sensor's frame rate (sim default)


def configure(demo: argparse.ArgumentParser) -> None:
    """Define ``lessmap demo`` (run by ``run_demo``)."""
    demo.description = (
        "Start the service on its embedded router, stream a simulated fleet "
        "(rooms, doors, a 270° laser) through Zenoh, show the live view, then print a "
        "summary scored against the simulator's ground truth."
    )
    demo.add_argument("--duration", type=positive_float, default=30.0, help="seconds")
    demo.add_argument("--robots", type=positive_int, default=3, help="robots")
    demo.add_argument("--rooms", type=positive_int, default=8, help="rooms")
    demo.add_argument("--seed", type=int, default=0, help="building and routes seed")
    demo.add_argument(
        "--speed",
        type=positive_float,
        default=10.0,
        help="simulated time per real second (10: 20 frames/s/robot)",
    )
    demo.add_argument("--json", action="store_true", help="print the summary as JSON")
    # The demo is its own router: it only listens.
    add_zenoh_options(
        demo,
        modes=None,
        connect=False,
        zenoh_config=False,
        connect_timeout=False,
        notes={"listen": f"the demo's router; default: {EMBEDDED_ENDPOINT}"},
    )


@dataclass(slots=True)
class DemoResult:
    """What the demo measured."""

    frames_published: int = 0
    transitions: dict[str, list[Transition]] = field(default_factory=dict)
    frames_applied: dict[str, int] = field(default_factory=dict)
    frames_missing: dict[str, int] = field(default_factory=dict)
    score: dict[str, Any] = field(default_factory=dict)


def run_demo(args: argparse.Namespace) -> int:
    """Run the demo; return 0 when every robot's frames were all applied."""
    from lessmap.runtime.service import Service
    from lessmap.sim.simulator import simulate

    frames_per_robot = max(10, int(args.duration * _RATE_HZ * args.speed))
    run = simulate(
        args.seed, rooms=args.rooms, robots=args.robots, frames_per_robot=frames_per_robot
    )
    # The demo's simulated robots are gone when it ends: nothing to keep for a restart, so
    # it leaves no session store behind in the user's state directory.
    args.listen = args.listen or [EMBEDDED_ENDPOINT]
    settings = load_settings(
        mode="router", listen=tuple(args.listen), instance="lessmap-demo", memory_only=True
    )
    service = Service(settings, ("scouting/multicast/enabled:false",))
    service.start()
    try:
        result = _stream_and_watch(run, args)
    finally:
        service.stop()
    _score(run, result)
    sys.stdout.write(_summary(run, result, as_json=args.json) + "\n")
    lost = sum(result.frames_missing.values())
    return 0 if lost == 0 and all(result.frames_applied.values()) else 1


def _stream_and_watch(run: SimRun, args: argparse.Namespace) -> DemoResult:
    from lessmap.cli.screens import live_fleet_screen
    from lessmap_client.adapters.replay import RecordedFrame, replay
    from lessmap_client.cli_client import follow
    from lessmap_client.fleet import FleetClient
    from lessmap_client.session import open_session
    from lessmap_client.watch import FleetView

    fleet = "demo"
    result = DemoResult()
    frames = [
        RecordedFrame(
            f["robot"], f["seq"], f["stamp"], f["features"], tuple(f["pose"]) if f["pose"] else None
        )
        for f in run.frames
    ]
    with open_session(args.listen[:1]) as session, FleetClient(fleet, session=session) as client:
        view = FleetView()
        publisher = threading.Thread(
            target=lambda: setattr(
                result,
                "frames_published",
                replay(frames, session, fleet, speed=args.speed).frames,
            ),
            name="demo-fleet",
            daemon=True,
        )
        publisher.start()
        with live_fleet_screen() as draw:
            follow(client, view, args.duration + 1.0, 0.5, "lessmap demo", fleet, draw=draw)
        publisher.join(timeout=max(5.0, args.duration))
        # Sessions end when the publishers close: read the final states back over Zenoh.
        deadline = time.monotonic() + 20.0
        states = []
        while time.monotonic() < deadline:
            states = client.states(fleet, timeout_s=1.0)
            if len(states) == args.robots and not any(s.open for s in states):
                break
            time.sleep(0.2)
        while (t := client.next_transition(timeout_s=0.5)) is not None:
            view.add_transition(t)
        for state in states:
            result.frames_applied[state.robot] = state.frames_applied
            result.frames_missing[state.robot] = state.frames_missing
        for transition in view.transitions:
            result.transitions.setdefault(transition.robot, []).append(transition)
    return result


def _score(run: SimRun, result: DemoResult) -> None:
    from lessmap.sim.groundtruth import score

    positions = {(row.robot, row.seq): (row.x, row.y) for row in run.truth}
    changes = [{"robot": c.robot, "seq": c.seq} for c in run.room_changes]
    figures = score(
        changes,
        result.transitions,
        positions=positions,
        doors=[(d.x, d.y) for d in run.building.doors],
        tolerance_frames=8,
        distance_m=2.0,
    )
    result.score = figures.as_dict()


def _summary(run: SimRun, result: DemoResult, *, as_json: bool) -> str:
    robots = sorted(result.frames_applied)
    per_robot = {
        robot: {
            "frames_applied": result.frames_applied[robot],
            "frames_missing": result.frames_missing[robot],
            "transitions": len(result.transitions.get(robot, [])),
            "room_changes": sum(1 for c in run.room_changes if c.robot == robot),
        }
        for robot in robots
    }
    summary = {
        "frames_published": result.frames_published,
        "robots": per_robot,
        "score": result.score,
    }
    if as_json:
        return json.dumps(summary)
    s = result.score
    lines = ["", "lessmap demo summary", "===================="]
    lines += [
        f"{robot}: {v['transitions']} transitions for {v['room_changes']} true room changes, "
        f"{v['frames_applied']} frames applied, {v['frames_missing']} lost"
        for robot, v in per_robot.items()
    ]
    door = s.get("precision_door")
    recall = s.get("recall")
    lines.append(
        f"transitions within ±2 m of a true door: "
        f"{'n/a' if door is None else f'{100 * door:.0f}%'}; room changes detected within "
        f"8 frames: {'n/a' if recall is None else f'{100 * recall:.0f}%'}"
    )
    return "\n".join(lines)

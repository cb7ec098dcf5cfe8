"""``lessmap rooms --fleet F``: the room map of a running fleet, redrawn as its robots walk.

Two inputs, as the viewer's: the robots' frames for their poses (a Zenoh subscriber on the
fleet's frames keys; no SDK call offers frames) and the service's transitions (an SDK
subscription, with the recent history of each robot). The frames subscriber is an advanced
one: on joining it fetches up to ``--history`` recent frames of each robot from the robot's
own publication cache (the SDK's robots keep 1,000), and a frame lost on the way is fetched
again, in order. Zenoh's and the SDK's threads only
queue, bounded: what does not fit is counted, never waited for. The main thread applies the
queue and, every ``--every`` seconds when something changed, draws the room map and replaces
the files. Each file is written beside its name and renamed over it, so a map server or a
viewer that reads it never sees half a map. Ends at ``--duration`` or SIGINT/SIGTERM, with a
last map.
"""

from __future__ import annotations

import json
import logging
import queue
import sys
import time
from typing import TYPE_CHECKING, Any

import zenoh
from zenoh import ext

from lessmap.floorplan.grid import FloorplanError
from lessmap.floorplan.live import LiveTrajectories
from lessmap_client.cli_options import zenoh_options
from lessmap_client.connection import Connection
from lessmap_schemas import keys
from lessmap_schemas.codec import decode_inbound
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import Frame, Transition

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable

    from lessmap.cli.foreground import StopSignal

__all__ = ["follow_fleet"]

log = logging.getLogger(__name__)

#: Messages queued between two passes of the main thread (a fleet's ~2 s at 50,000 a second).
QUEUE_SIZE = 100_000
#: A fleet whose transitions arrive but whose frames do not: said once, after this long.
NO_FRAMES_WARNING_S = 10.0
#: Longest wait for a message before the stop signal is looked at again.
STOP_CHECK_S = 0.2

Item = tuple[str, bytes] | Transition


def follow_fleet(
    args: argparse.Namespace,
    stop: StopSignal,
    draw: Callable[[LiveTrajectories], dict[str, Any] | None],
) -> int:
    """Follow ``args.fleet`` until ``stop`` or ``args.duration``; print a JSON line per map.

    ``draw`` makes and writes the room map of what is known, returning the line to print
    (None: nothing to draw yet).

    Raises:
        FloorplanError: no frame with a pose arrived before the end.
    """
    trajectories = LiveTrajectories()
    inbox: queue.Queue[Item] = queue.Queue(QUEUE_SIZE)

    def put(item: Item) -> None:  # Zenoh's and the SDK's threads: queue only
        try:
            inbox.put_nowait(item)
        except queue.Full:
            trajectories.counts["dropped: queue full"] += 1

    def on_frame(sample: zenoh.Sample) -> None:
        put((str(sample.key_expr), sample.payload.to_bytes()))

    net = zenoh_options(args)
    frames_key = keys.frames(args.fleet, keys.ANY)
    session = net.open_session()
    with session, Connection.from_session(session) as conn:
        frames = ext.declare_advanced_subscriber(
            session,
            frames_key,
            on_frame,
            history=(
                ext.HistoryConfig(detect_late_publishers=True, max_samples=args.history)
                if args.history > 0
                else None
            ),
            recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
        )
        transitions = conn.subscribe_transitions(args.fleet, handler=put)
        log.info("following fleet %s at %s (frames on %s)", args.fleet, net.where, frames_key)
        started = time.monotonic()
        deadline = float("inf") if args.duration is None else started + args.duration
        next_draw = started + args.every
        warned = False
        try:
            while not stop.event.is_set():
                now = time.monotonic()
                if now >= deadline:
                    break
                _apply(inbox, trajectories, until=min(next_draw, deadline, now + STOP_CHECK_S))
                if not warned and _no_frames(trajectories, time.monotonic() - started):
                    warned = True
                    log.warning(
                        "transitions of fleet %s arrive but no frame has in %g s: on a "
                        "secured site an app's role cannot read frames (use a viewer's)",
                        args.fleet,
                        NO_FRAMES_WARNING_S,
                    )
                if time.monotonic() >= next_draw:
                    next_draw = time.monotonic() + args.every
                    _draw(trajectories, draw)
        finally:
            frames.undeclare()
            transitions.close()
        _apply(inbox, trajectories, until=time.monotonic())
    if trajectories.poses == 0:
        msg = (
            f"no frame with a pose of fleet {args.fleet} arrived at {net.where} "
            f"({trajectories.counts['frames']} frames, "
            f"{trajectories.counts['frames without a pose']} without a pose)"
        )
        raise FloorplanError(msg)
    _draw(trajectories, draw, final=True)
    return 0


def _apply(inbox: queue.Queue[Item], trajectories: LiveTrajectories, *, until: float) -> None:
    """Apply queued messages until the queue is empty at ``until`` (monotonic seconds)."""
    while True:
        wait = until - time.monotonic()
        try:
            item = inbox.get(timeout=wait) if wait > 0 else inbox.get_nowait()
        except queue.Empty:
            return
        if isinstance(item, Transition):
            trajectories.add_transition(item)
            continue
        key, payload = item
        try:
            _fleet, robot, _stream = keys.parse_robot_key(key)
            message = decode_inbound(payload)
        except WireError:  # a bad key or payload: counted, the others go on
            trajectories.counts["undecodable frames"] += 1
            continue
        if isinstance(message, Frame):
            trajectories.add_frame(robot, message)


def _no_frames(trajectories: LiveTrajectories, elapsed_s: float) -> bool:
    counts = trajectories.counts
    return elapsed_s >= NO_FRAMES_WARNING_S and counts["transitions"] > 0 and not counts["frames"]


def _draw(
    trajectories: LiveTrajectories,
    draw: Callable[[LiveTrajectories], dict[str, Any] | None],
    *,
    final: bool = False,
) -> None:
    """Draw when something changed; the last map always, and its failure is the command's.

    Raises:
        FloorplanError: the last map cannot be drawn (poses off the map, no robot asked for).
    """
    if not (trajectories.changed or final):
        return
    trajectories.changed = False
    try:
        record = draw(trajectories)
    except FloorplanError as exc:
        if final:
            raise
        log.warning("no room map this time: %s", exc)  # e.g. poses off the map: retried
        return
    if record is None:
        if final:
            msg = "no pose of the robots asked for (--robot) arrived"
            raise FloorplanError(msg)
        return
    record["counts"] = dict(sorted(trajectories.counts.items()))
    record["final"] = final
    sys.stdout.write(json.dumps(record) + "\n")
    sys.stdout.flush()

"""Client-side subcommands of ``lessmap``: replay and watch (wired in by ``lessmap.cli``)."""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap_client.cli_options import (
    add_deprecated_alias,
    add_zenoh_options,
    non_negative_float,
    positive_float,
    zenoh_options,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap_client.adapters.replay import ReplayStats
    from lessmap_client.fleet import FleetClient
    from lessmap_client.subscription import Subscription
    from lessmap_client.watch import FleetView
    from lessmap_schemas.messages import Error, SessionState, Transition

    #: Draws a fleet's view with a title (``lessmap watch`` on a terminal).
    Draw = Callable[[FleetView, str], None]

#: Seconds between two progress lines of ``replay`` on a terminal.
PROGRESS_S = 5.0


def configure_replay(rep: argparse.ArgumentParser) -> None:
    """Define ``lessmap replay`` (run by ``run_replay``)."""
    rep.description = (
        "Publish FILE.frames.jsonl paced by its stamps (--speed), or as fast as "
        "possible (--fast). Each robot in the file gets its own publisher and session. "
        "The whole file is checked before anything is published. At the end, the service's "
        "own counts are read back: the JSON summary on stdout has, per robot, the frames "
        "offered, applied, missing and rejected; the exit code is 0 only when the service "
        "applied every frame offered, with none missing or rejected."
    )
    rep.add_argument("file", type=Path, metavar="FILE")
    rep.add_argument("--fleet", default="replay", help="fleet name (default: replay)")
    rep.add_argument("--robot-prefix", default="", help="prefix for the file's robot ids")
    pace = rep.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=positive_float, default=1.0, help="playback rate")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    rep.add_argument(
        "--settle",
        type=positive_float,
        default=10.0,
        metavar="S",
        help="after publishing, wait for the service's final counts until they have not "
        "changed for S seconds",
    )
    rep.add_argument(
        "--progress",
        type=non_negative_float,
        default=None,
        metavar="S",
        help="a progress line on stderr every S seconds (0: none; default: every "
        f"{PROGRESS_S:g} s when stderr is a terminal, none with -q or into a pipe)",
    )
    group = add_zenoh_options(rep)
    add_deprecated_alias(
        group,
        "--wait-service",
        use="--connect-timeout",
        dest="connect_timeout",
        type=positive_float,
    )


def configure_watch(watch: argparse.ArgumentParser) -> None:
    """Define ``lessmap watch`` (run by ``run_watch``)."""
    watch.add_argument("--fleet", default="*", help="fleet to follow (default: all)")
    watch.add_argument(
        "--duration",
        type=non_negative_float,
        metavar="S",
        help="stop after S seconds, the wait for a router included (default: until Ctrl-C)",
    )
    watch.add_argument(
        "--interval", type=positive_float, default=1.0, metavar="S", help="refresh period"
    )
    watch.add_argument(
        "--shared-features",
        action="store_true",
        help="the fleet's feature ids are global: show each robot's place (its fleet area, "
        "named robot:area by its first member) and the places robots share, from "
        "fleet_area_graph every --places-interval seconds (needs one --fleet)",
    )
    watch.add_argument(
        "--places-interval",
        type=positive_float,
        default=5.0,
        metavar="S",
        help="seconds between two fleet area queries",
    )
    add_zenoh_options(watch)


def run_replay(args: argparse.Namespace) -> int:
    """Run ``lessmap replay``."""
    from lessmap_client.adapters.replay import (
        ProgressReporter,
        ReplayStats,
        read_recorded,
        replay,
        settled_states,
    )
    from lessmap_schemas.framesfile import sparse_frames_warning

    net = zenoh_options(args)
    # Every line is checked before the first frame goes out.
    frames = list(read_recorded(args.file, robot_prefix=args.robot_prefix))
    if not frames:
        sys.stderr.write(f"lessmap replay: {args.file}: no frames to publish\n")
        return 1
    features = sum(len(frame.features) for frame in frames)
    warning = sparse_frames_warning(str(args.file), len(frames), features)
    if warning is not None:
        sys.stderr.write(f"lessmap replay: {warning}\n")
    stats = ReplayStats()
    batches = Batches()
    with net.connection() as conn:
        served = conn.wait_for_service(net.connect_timeout_s)
        if not served:
            sys.stderr.write("lessmap replay: no lessmap service answered; publishing anyway\n")
        reports = conn.subscribe_errors(args.fleet)
        decisions = conn.subscribe_transitions(args.fleet, history=False, handler=batches.add)

        def sessions() -> set[tuple[str, str]]:
            return {(name, r.session_id) for name, r in dict(stats.per_robot).items()}

        def acknowledged() -> int:
            ours = sessions()
            states = conn.states(args.fleet, timeout_s=1.0)
            return sum(s.frames_applied for s in states if (s.robot, s.session) in ours)

        def say(line: str) -> None:
            sys.stderr.write(f"lessmap replay: {line}\n")
            sys.stderr.flush()

        reporter = ProgressReporter(
            _progress_interval_s(args), lambda: stats.frames, acknowledged, say, len(frames)
        ).start()
        try:
            replay(
                frames,
                conn,
                args.fleet,
                speed=None if args.fast else args.speed,
                robot_prefix=args.robot_prefix,
                stats=stats,
                # Each robot's first frame waits until its partition's owner can hear it.
                wait_service_s=net.connect_timeout_s if served else 0.0,
            )
            final = settled_states(
                lambda: conn.states(args.fleet, timeout_s=1.0), stats, quiet_s=args.settle
            )
        finally:
            reporter.stop()
        counted = _count_reports(reports, sessions())
        decisions.close()
    summary, problems = replay_summary(stats, final, counted)
    summary["coalesced"] = batches.coalesced(sessions())
    sys.stdout.write(json.dumps(summary) + "\n")
    if summary["coalesced"]["transitions"]:
        sys.stderr.write(f"lessmap replay: {coalescing_note(summary['coalesced'])}\n")
    if problems:
        sys.stderr.write(
            "lessmap replay: the service did not apply every frame offered: "
            + ", ".join(problems)
            + "\n"
        )
        return 1
    return 0


def _progress_interval_s(args: argparse.Namespace) -> float:
    """``--progress``, else a line every few seconds on a terminal, none into a pipe."""
    if getattr(args, "quiet", False):
        return 0.0
    if args.progress is not None:
        return float(args.progress)
    return PROGRESS_S if sys.stderr.isatty() else 0.0


class Batches:
    """The frames each transition's decision covered, as the service reports them."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: list[tuple[str, str, int]] = []  # robot, session, batch_frames

    def add(self, transition: Transition) -> None:
        """Note one transition (called on the subscription's thread)."""
        with self._lock:
            self._seen.append((transition.robot, transition.session, transition.batch_frames))

    def coalesced(self, sessions: set[tuple[str, str]]) -> dict[str, int]:
        """Return how many of the sessions' transitions were decided over several frames."""
        with self._lock:
            batches = [b for robot, session, b in self._seen if (robot, session) in sessions]
        over = [b for b in batches if b > 1]
        return {
            "transitions": len(over),
            "of": len(batches),
            "largest_batch_frames": max(over, default=1),
        }


def coalescing_note(coalesced: dict[str, int]) -> str:
    """Say that the service decided over batches of frames, and what that changes."""
    return (
        f"the service was behind and decided over batches of frames (up to "
        f"{coalesced['largest_batch_frames']} a decision; {coalesced['transitions']} of the "
        f"{coalesced['of']} transitions seen): fewer decisions find fewer transitions than "
        "lessmap segment does on the same file; replay at a --speed the service keeps up with "
        "to compare"
    )


def _count_reports(
    reports: Subscription[Error], sessions: set[tuple[str, str]]
) -> dict[str, dict[str, int]]:
    """Drain the error subscription: reports per robot and code, for the replayed sessions."""
    counted: dict[str, dict[str, int]] = {}
    while (report := reports.try_recv()) is not None:
        if report.robot is not None and (report.robot, report.session) in sessions:
            codes = counted.setdefault(report.robot, {})
            codes[str(report.code)] = codes.get(str(report.code), 0) + 1
    reports.close()
    return counted


def replay_summary(
    stats: ReplayStats,
    final: dict[str, SessionState],
    reports: dict[str, dict[str, int]],
) -> tuple[dict[str, Any], list[str]]:
    """Return the JSON summary and, per robot the service failed, what went wrong."""
    robots: dict[str, Any] = {}
    problems: list[str] = []
    for name, record in sorted(stats.per_robot.items()):
        state = final.get(name)
        entry: dict[str, Any] = {
            "session": record.session_id,
            "offered": record.offered,
            "applied": None if state is None else state.frames_applied,
            "missing": None if state is None else state.frames_missing,
            "rejected": None if state is None else state.frames_rejected,
            "duplicate": None if state is None else state.frames_duplicate,
            "transitions": None if state is None else state.transitions,
            "closed_by_service": record.closed_by_service,
            "skipped": record.skipped,
            "errors": reports.get(name, {}),
        }
        robots[name] = entry
        wrong = []
        if state is None:
            wrong.append("no final state from the service")
        else:
            if state.open:
                wrong.append("session still open")
            if state.frames_missing:
                wrong.append(f"{state.frames_missing} missing")
            if state.frames_rejected:
                wrong.append(f"{state.frames_rejected} rejected")
            if state.frames_applied != record.offered:
                wrong.append(f"{state.frames_applied} of {record.offered} applied")
        if record.closed_by_service or reports.get(name, {}).get("SESSION_CLOSED"):
            wrong.append("session closed by the service")
        if record.skipped:
            wrong.append(f"{record.skipped} not sent")
        if wrong:
            problems.append(f"{name} ({', '.join(wrong)})")
    applied = sum(e["applied"] or 0 for e in robots.values())
    summary = {
        "frames": stats.frames,
        "robots": stats.robots,
        "elapsed_s": round(stats.elapsed_s, 3),
        "applied": applied,
        "ok": not problems,
        "per_robot": robots,
    }
    return summary, problems


def run_watch(args: argparse.Namespace, draw: Draw | None = None) -> int:
    """Run ``lessmap watch``: transition lines and a final table, or ``draw`` the view."""
    from lessmap_client.fleet import FleetClient
    from lessmap_client.watch import FleetView

    if args.shared_features and "*" in args.fleet:
        sys.stderr.write("lessmap watch: --shared-features follows one fleet: give --fleet\n")
        return 1
    view = FleetView()
    net = zenoh_options(args)
    started = time.monotonic()
    # --duration bounds the whole run, the wait for a router included.
    wait_s = net.connect_timeout_s
    if args.duration is not None:
        wait_s = min(wait_s, args.duration)
    with (
        net.open_session(timeout_s=wait_s) as session,
        FleetClient(args.fleet, session=session) as client,
    ):
        left_s = None if args.duration is None else args.duration - (time.monotonic() - started)
        follow(
            client,
            view,
            None if left_s is None else max(0.0, left_s),
            args.interval,
            title=f"lessmap watch {args.fleet}",
            places_every_s=args.places_interval if args.shared_features else None,
            draw=draw,
        )
    if draw is None:
        sys.stdout.write(view.table() + "\n")
    return 0


def follow(
    client: FleetClient,
    view: FleetView,
    duration_s: float | None,
    interval_s: float,
    title: str,
    fleet: str | None = None,
    places_every_s: float | None = None,
    draw: Draw | None = None,
) -> None:
    """Feed the view from the client until ``duration_s`` passes (or Ctrl-C).

    Without ``draw``, each transition is a line on stdout; with it, the view is drawn every
    ``interval_s``. With ``places_every_s``, also the fleet's places (``fleet_area_graph``
    with shared features) that often: a query for every robot's graph, so less often.
    """
    from lessmap_client.fleet_areas import FleetParams

    deadline = None if duration_s is None else time.monotonic() + duration_s
    next_refresh = next_places = 0.0
    try:
        while deadline is None or time.monotonic() < deadline:
            transition = client.next_transition(timeout_s=0.1)
            if transition is not None:
                line = view.add_transition(transition)
                if draw is None:
                    sys.stdout.write(line + "\n")
                    sys.stdout.flush()
            now = time.monotonic()
            if now >= next_refresh:
                next_refresh = now + interval_s
                for state in client.states(fleet, timeout_s=0.5):
                    view.add_state(state)
                if places_every_s is not None and now >= next_places:
                    next_places = now + places_every_s
                    places = fleet or client.fleet
                    graph = client.fleet_area_graph(
                        places, params=FleetParams(shared_features=True), timeout_s=0.5
                    )
                    view.add_fleet_graph(places, graph)
                if draw is not None:
                    draw(view, title)
    except KeyboardInterrupt:
        pass

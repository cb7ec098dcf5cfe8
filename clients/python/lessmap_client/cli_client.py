"""Client-side subcommands of ``lessmap``: replay, sim, watch (wired in by ``lessmap.cli``)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap_client.session import DEFAULT_ENDPOINT

if TYPE_CHECKING:
    from lessmap_client.adapters.replay import ReplayStats
    from lessmap_client.fleet import FleetClient
    from lessmap_client.subscription import Subscription
    from lessmap_client.watch import FleetView
    from lessmap_schemas.messages import Error, SessionState


def add_zenoh_options(parser: argparse.ArgumentParser) -> None:
    """Add ``-e/--connect`` (repeatable) and ``-m/--mode``."""
    parser.add_argument(
        "-e",
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"lessmap router endpoint (repeatable; default {DEFAULT_ENDPOINT})",
    )
    parser.add_argument("-m", "--mode", choices=["client", "peer"], default="client")


def endpoints(args: argparse.Namespace) -> list[str]:
    """Return the endpoints to connect to."""
    return list(args.connect) if args.connect else [DEFAULT_ENDPOINT]


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
    pace.add_argument("--speed", type=float, default=1.0, help="playback rate (default 1.0)")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    rep.add_argument(
        "--wait-service",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds to wait for a service instance first (default 10)",
    )
    rep.add_argument(
        "--settle",
        type=float,
        default=10.0,
        metavar="S",
        help="after publishing, wait for the service's final counts until they have not "
        "changed for S seconds (default 10)",
    )
    rep.add_argument(
        "--progress",
        type=float,
        default=5.0,
        metavar="S",
        help="a progress line on stderr every S seconds (default 5; 0: none)",
    )
    add_zenoh_options(rep)


def configure_watch(watch: argparse.ArgumentParser) -> None:
    """Define ``lessmap watch`` (run by ``run_watch``)."""
    watch.add_argument("--fleet", default="*", help="fleet to follow (default: all)")
    watch.add_argument("--duration", type=float, help="stop after this many seconds")
    watch.add_argument("--interval", type=float, default=1.0, help="refresh period, seconds")
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
    from lessmap_client.connection import connect

    if not args.fast and args.speed <= 0:
        sys.stderr.write(f"lessmap replay: --speed must be positive, got {args.speed:g}\n")
        return 1
    # Every line is checked before the first frame goes out.
    frames = list(read_recorded(args.file, robot_prefix=args.robot_prefix))
    stats = ReplayStats()
    with connect(endpoints(args), mode=args.mode) as conn:
        if not conn.wait_for_service(args.wait_service):
            sys.stderr.write("lessmap replay: no lessmap service answered; publishing anyway\n")
        reports = conn.subscribe_errors(args.fleet)

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
            args.progress, lambda: stats.frames, acknowledged, say, len(frames)
        ).start()
        try:
            replay(
                frames,
                conn,
                args.fleet,
                speed=None if args.fast else args.speed,
                robot_prefix=args.robot_prefix,
                stats=stats,
            )
            final = settled_states(
                lambda: conn.states(args.fleet, timeout_s=1.0), stats, quiet_s=args.settle
            )
        finally:
            reporter.stop()
        counted = _count_reports(reports, sessions())
    summary, problems = replay_summary(stats, final, counted)
    sys.stdout.write(json.dumps(summary) + "\n")
    if problems:
        sys.stderr.write(
            "lessmap replay: the service did not apply every frame offered: "
            + ", ".join(problems)
            + "\n"
        )
        return 1
    return 0


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


def run_watch(args: argparse.Namespace) -> int:
    """Run ``lessmap watch``."""
    from lessmap_client.fleet import FleetClient
    from lessmap_client.session import open_session
    from lessmap_client.watch import FleetView

    view = FleetView()
    with (
        open_session(endpoints(args), args.mode) as session,
        FleetClient(args.fleet, session=session) as client,
    ):
        follow(client, view, args.duration, args.interval, title=f"lessmap watch {args.fleet}")
    sys.stdout.write(view.table() + "\n")
    return 0


def follow(
    client: FleetClient,
    view: FleetView,
    duration_s: float | None,
    interval_s: float,
    title: str,
    fleet: str | None = None,
) -> None:
    """Feed the view from the client until ``duration_s`` passes (or Ctrl-C)."""
    tty = sys.stdout.isatty()
    deadline = None if duration_s is None else time.monotonic() + duration_s
    next_refresh = 0.0
    try:
        while deadline is None or time.monotonic() < deadline:
            transition = client.next_transition(timeout_s=0.1)
            if transition is not None:
                line = view.add_transition(transition)
                if not tty:
                    sys.stdout.write(line + "\n")
                    sys.stdout.flush()
            now = time.monotonic()
            if now >= next_refresh:
                next_refresh = now + interval_s
                for state in client.states(fleet, timeout_s=0.5):
                    view.add_state(state)
                if tty:
                    sys.stdout.write("\x1b[2J\x1b[H" + view.screen(title) + "\n")
                    sys.stdout.flush()
    except KeyboardInterrupt:
        pass

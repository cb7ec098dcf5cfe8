"""Client-side subcommands of ``lessmap``: replay, sim, watch (wired in by ``lessmap.cli``)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap_client.session import DEFAULT_ENDPOINT

if TYPE_CHECKING:
    from lessmap_client.fleet import FleetClient
    from lessmap_client.watch import FleetView


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
        "possible (--fast). Each robot in the file gets its own publisher and session."
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
    add_zenoh_options(rep)


def configure_watch(watch: argparse.ArgumentParser) -> None:
    """Define ``lessmap watch`` (run by ``run_watch``)."""
    watch.add_argument("--fleet", default="*", help="fleet to follow (default: all)")
    watch.add_argument("--duration", type=float, help="stop after this many seconds")
    watch.add_argument("--interval", type=float, default=1.0, help="refresh period, seconds")
    add_zenoh_options(watch)


class Progress:
    """A one-line progress counter on stderr, only on a terminal."""

    def __init__(self, total: int | None, label: str) -> None:
        self._total = total
        self._label = label
        self._enabled = sys.stderr.isatty()
        self._last_s = 0.0

    def __call__(self, done: int) -> None:
        """Show ``done`` (at most five times a second)."""
        now = time.monotonic()
        if not self._enabled or (now - self._last_s < 0.2 and done != self._total):
            return
        self._last_s = now
        if self._total:
            width = 30
            filled = int(width * done / self._total)
            bar = "#" * filled + "." * (width - filled)
            sys.stderr.write(f"\r{self._label} [{bar}] {done}/{self._total}")
        else:
            sys.stderr.write(f"\r{self._label} {done}")
        sys.stderr.flush()

    def close(self) -> None:
        """End the line."""
        if self._enabled:
            sys.stderr.write("\n")


def run_replay(args: argparse.Namespace) -> int:
    """Run ``lessmap replay``."""
    from lessmap_client.adapters.replay import read_recorded, replay
    from lessmap_client.session import open_session, wait_for_service

    frames = list(read_recorded(args.file))
    with open_session(endpoints(args), args.mode) as session:
        if not wait_for_service(session, args.wait_service):
            sys.stderr.write("lessmap replay: no lessmap service answered; publishing anyway\n")
        progress = Progress(len(frames), "replay")
        stats = replay(
            frames,
            session,
            args.fleet,
            speed=None if args.fast else args.speed,
            robot_prefix=args.robot_prefix,
            on_frame=progress,
        )
        progress.close()
    summary = {
        "frames": stats.frames,
        "robots": stats.robots,
        "elapsed_s": round(stats.elapsed_s, 3),
    }
    sys.stdout.write(json.dumps(summary) + "\n")
    return 0


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

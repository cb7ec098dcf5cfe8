"""The ``lessmap`` command line: one entry point, one subcommand per job.

Each subcommand lives in its own module, named in ``COMMANDS`` and imported only when that
command runs: ``lessmap --version`` and ``lessmap --help`` load neither numpy nor zenoh. A
command module defines ``configure(parser)`` (its arguments) and ``run(args) -> int``
(spelled otherwise when one module holds several commands).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import TYPE_CHECKING, NamedTuple

from lessmap import __version__
from lessmap.cli.logfmt import configure as configure_logging

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence


class Command(NamedTuple):
    """Where a subcommand is defined, and its one-line help."""

    module: str
    help: str
    configure: str = "configure"
    run: str = "run"


#: Every subcommand, in the order ``lessmap --help`` lists them.
COMMANDS: dict[str, Command] = {
    "serve": Command(
        "lessmap.runtime.daemon", "run the partition service (a Zenoh daemon for many robots)"
    ),
    "router": Command(
        "lessmap.runtime.router",
        "run a plain Zenoh router for several service instances (no lessmap service in it)",
    ),
    "status": Command(
        "lessmap_client.cli_client",
        "instances, partitions, owners, standbys and lag of the running service",
        "configure_status",
        "run_status",
    ),
    "segment": Command(
        "lessmap.cli.segment", "segment a recorded frames file offline (one session per robot)"
    ),
    "rooms": Command(
        "lessmap.floorplan.command",
        "a room map: every free cell of an occupancy map labelled by area (map_server files)",
    ),
    "demo": Command(
        "lessmap.cli.demo",
        "run the service, a simulated fleet and the live view for a bounded time",
        run="run_demo",
    ),
    "replay": Command(
        "lessmap_client.cli_client",
        "publish a recorded frames file to the service (one publisher per robot)",
        "configure_replay",
        "run_replay",
    ),
    "watch": Command(
        "lessmap_client.cli_client",
        "live view of a fleet: one row per robot, transitions as they arrive",
        "configure_watch",
        "run_watch",
    ),
    "areas": Command(
        "lessmap.cli.areas",
        "a running fleet's places: its robots' area graphs merged into fleet areas",
    ),
    "sim": Command(
        "lessmap.sim.command",
        "simulate a fleet in a building; write frames and ground truth, or publish live",
    ),
    "eval": Command(
        "lessmap.evaluation.commands",
        "information loss e (Eq. 5) of LESS-mapping vs. baselines, and a threshold sweep",
        "configure_eval",
        "run_eval",
    ),
    "plot": Command(
        "lessmap.evaluation.commands",
        "PNG figures: trajectory by submap, Ncut/λ2 over frames, reordered W, sweep",
        "configure_plot",
        "run_plot",
    ),
    "certs": Command(
        "lessmap.security.certs",
        "write a test site's CA, certificates and mTLS + access-control configs",
    ),
    "ros": Command(
        "lessmap.ros.cli_ros",
        "bridge ROS 2 landmark topics (rmw_zenoh) to lessmap frames, live (lessmap[ros])",
    ),
    "import": Command(
        "lessmap.ros.cli_ros",
        "convert landmark topics of a rosbag2 (sqlite3, MCAP) or ROS 1 bag to a frames file",
        "configure_import",
        "run_import",
    ),
    "view": Command(
        "lessmap.viz.cli_viz",
        "show a fleet in Foxglove or Lichtblick: a Foxglove WebSocket server (lessmap[viz])",
        "configure_view",
        "run_view",
    ),
    "record": Command(
        "lessmap.viz.cli_viz",
        "record a fleet's view (the channels of lessmap view) to an MCAP file (lessmap[viz])",
        "configure_record",
        "run_record",
    ),
}

#: Failures a user can fix: one line on stderr and exit code 1, no traceback. Named by
#: module, so none is imported for nothing: an exception whose module was never loaded
#: cannot have been raised.
KNOWN_EXCEPTIONS: tuple[tuple[str, str], ...] = (
    ("lessmap.errors", "ConfigError"),
    ("lessmap.errors", "DatasetError"),
    ("lessmap.core.errors", "GraphError"),
    ("lessmap.floorplan.grid", "FloorplanError"),  # a map, label image or truth file
    ("lessmap_schemas.errors", "WireError"),  # a frame breaks the wire contract (replay)
    ("lessmap_client.adapters.replay", "ReplayError"),  # a malformed file given to replay
    ("builtins", "FileNotFoundError"),
    ("builtins", "IsADirectoryError"),
    ("builtins", "NotADirectoryError"),
    ("builtins", "PermissionError"),
    ("builtins", "ConnectionError"),  # the client commands could not reach a router
)


#: Top-level modules of the optional extras, and the extra that installs each.
OPTIONAL_MODULES = {
    "matplotlib": "eval",
    "cryptography": "security",
    "rosbags": "ros",
    "foxglove": "viz",
}


def is_known(exc: BaseException) -> bool:
    """Return whether ``exc`` is a user's error (one line, exit 1) rather than a bug."""
    for module, name in KNOWN_EXCEPTIONS:
        loaded = sys.modules.get(module)
        kind = getattr(loaded, name, None)
        if isinstance(kind, type) and isinstance(exc, kind):
            return True
    return False


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level parser: global options, then COMMAND and its arguments."""
    width = max(map(len, COMMANDS)) + 2
    listing = "\n".join(f"  {name:<{width}}{c.help}" for name, c in COMMANDS.items())
    parser = argparse.ArgumentParser(
        prog="lessmap",
        description="Online environment segmentation for robot fleets "
        "(LESS-mapping spectral covisibility partitioning) over Eclipse Zenoh.",
        epilog=f"commands:\n{listing}\n\n'lessmap COMMAND --help' describes one command.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"lessmap {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    parser.add_argument(
        "--log-format",
        choices=["text", "json"],
        default="text",
        help="stderr log lines as text or one JSON object per line (default: text)",
    )
    parser.add_argument("command", metavar="COMMAND", choices=COMMANDS, help="see below")
    parser.add_argument("arguments", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    return parser


def command_parser(name: str) -> tuple[argparse.ArgumentParser, Callable[..., int]]:
    """Import the module of command ``name``; return its parser and its run function."""
    command = COMMANDS[name]
    module = importlib.import_module(command.module)
    parser = argparse.ArgumentParser(prog=f"lessmap {name}", description=command.help)
    getattr(module, command.configure)(parser)
    run: Callable[..., int] = getattr(module, command.run)
    return parser, run


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the process exit code."""
    top = build_parser().parse_args(argv)
    parser, run = command_parser(top.command)
    args = parser.parse_args(top.arguments)
    args.command, args.verbose, args.log_format = top.command, top.verbose, top.log_format
    # The command line of this process (not a call from Python code, e.g. a test): a daemon
    # may then restart itself with other allocator settings (``serve``).
    args.own_process = argv is None
    # A daemon reports its lifecycle (INFO) by default; one-shot tools only warnings.
    daemons = ("serve", "router", "ros", "view", "record")
    base = logging.INFO if args.command in daemons else logging.WARNING
    configure_logging(max(logging.DEBUG, base - 10 * args.verbose), args.log_format)
    try:
        code = run(args)
        sys.stdout.flush()  # a closed pipe shows here, while we can still handle it
    except BrokenPipeError:
        return _closed_pipe()
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.partition(".")[0] not in OPTIONAL_MODULES:
            raise
        extra = OPTIONAL_MODULES[exc.name.partition(".")[0]]
        print(
            f"lessmap {args.command}: this needs {exc.name}, from the optional extra: "
            f"pip install 'lessmap[{extra}]'",
            file=sys.stderr,
        )
        return 1
    except Exception as exc:
        if not is_known(exc):
            raise
        print(f"lessmap {args.command}: {exc}", file=sys.stderr)
        return 1
    return code


def _closed_pipe() -> int:
    """Exit quietly when stdout was closed early (``lessmap segment x | head -1``)."""
    # Python flushes stdout again at exit and would report the broken pipe there: point
    # stdout at /dev/null first (as the Python docs on SIGPIPE advise).
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no real file descriptor (e.g. a test's capture)
        pass
    finally:
        os.close(devnull)
    return 0

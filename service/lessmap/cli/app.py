"""The ``lessmap`` command line: one entry point, one subcommand per job.

Each subcommand lives in its own module, named in ``COMMANDS`` and imported only when that
command runs: ``lessmap --version`` and ``lessmap --help`` load neither numpy nor zenoh. A
command module defines ``configure(parser)`` (its arguments) and ``run(args) -> int``
(spelled otherwise when one module holds several commands).

Exit codes: 0 done; 1 the command ran and failed (a missing or malformed file, no router,
a port taken); 2 the command line itself is wrong (an unknown option, a value of the wrong
kind or out of range). Either way one line on stderr, ``lessmap COMMAND: what to do``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import TYPE_CHECKING, NamedTuple, NoReturn

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
        "lessmap.cli.router",
        "run a plain Zenoh router for several service instances (no lessmap service in it)",
    ),
    "status": Command(
        "lessmap.cli.screens",
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
        "lessmap.cli.screens",
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
    ("lessmap_client.errors", "ZenohConfigError"),  # a Zenoh config or endpoint, a port taken
    ("zenoh", "ZError"),  # any other refusal of Zenoh's (its text is cleaned)
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


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line: what is wrong, where to look."""

    def error(self, message: str) -> NoReturn:
        """Print ``PROG: MESSAGE (PROG --help)`` on stderr and exit 2."""
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's default in its help, unless the text already says it or it is unset."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if _unset(action.default) or not action.option_strings or "default" in text:
            return text
        return f"{text} (default: %(default)s)" if text else "default: %(default)s"


def _unset(default: object) -> bool:
    """Whether an option's default means "not given" (None, off, empty), not a value like 0."""
    empty = isinstance(default, list | tuple) and not default
    return default is None or default is False or default is argparse.SUPPRESS or empty


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level parser: global options, then COMMAND and its arguments."""
    width = max(map(len, COMMANDS)) + 2
    listing = "\n".join(f"  {name:<{width}}{c.help}" for name, c in COMMANDS.items())
    parser = Parser(
        prog="lessmap",
        description="Online environment segmentation for robot fleets "
        "(LESS-mapping spectral covisibility partitioning) over Eclipse Zenoh.",
        epilog=f"commands:\n{listing}\n\n'lessmap COMMAND --help' describes one command. "
        "Exit codes: 0 done, 1 failed (one line on stderr says why), 2 a wrong command line.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"lessmap {__version__}")
    add_global_options(parser, defaults=True)
    parser.add_argument("command", metavar="COMMAND", choices=COMMANDS, help="see below")
    parser.add_argument("arguments", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    return parser


def add_global_options(parser: argparse.ArgumentParser, *, defaults: bool) -> None:
    """Add ``-v``, ``-q`` and ``--log-format``, accepted before the command and after it."""
    group = parser.add_argument_group("global options (before or after COMMAND)")
    group.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0 if defaults else argparse.SUPPRESS,
        help="more logging (repeat for more)",
    )
    group.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=False if defaults else argparse.SUPPRESS,
        help="no progress bars (they are drawn on stderr only when it is a terminal)",
    )
    group.add_argument(
        "--log-format",
        choices=["text", "json"],
        default="text" if defaults else argparse.SUPPRESS,
        help="stderr log lines as text or one JSON object per line (default: text)",
    )


def command_parser(name: str) -> tuple[argparse.ArgumentParser, Callable[..., int]]:
    """Import the module of command ``name``; return its parser and its run function."""
    command = COMMANDS[name]
    module = importlib.import_module(command.module)
    parser = Parser(prog=f"lessmap {name}", description=command.help, formatter_class=HelpFormatter)
    getattr(module, command.configure)(parser)
    add_global_options(parser, defaults=False)
    run: Callable[..., int] = getattr(module, command.run)
    return parser, run


def short_usage() -> str:
    """What bare ``lessmap`` prints: the grammar and the commands, in three lines."""
    return (
        "usage: lessmap [-v] [-q] [--log-format text|json] COMMAND [ARGUMENTS]\n"
        f"commands: {', '.join(COMMANDS)}\n"
        "'lessmap --help' says what each does; 'lessmap COMMAND --help' how to run it.\n"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the process exit code."""
    if not (sys.argv[1:] if argv is None else argv):
        sys.stderr.write(short_usage())
        return 2
    top = build_parser().parse_args(argv)
    parser, run = command_parser(top.command)
    args = parser.parse_args(top.arguments)
    args.command = top.command
    args.verbose = top.verbose + getattr(args, "verbose", 0)
    args.log_format = getattr(args, "log_format", top.log_format)
    args.quiet = top.quiet or getattr(args, "quiet", False)
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
    except KeyboardInterrupt:
        return 130  # Ctrl-C: the shell's code for SIGINT, and no traceback
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.partition(".")[0] not in OPTIONAL_MODULES:
            raise
        extra = OPTIONAL_MODULES[exc.name.partition(".")[0]]
        print(
            f"lessmap {args.command}: this needs {exc.name}, from lessmap's optional extra "
            f"{extra}: pip install '.[{extra}]' in the repository (README, Install)",
            file=sys.stderr,
        )
        return 1
    except Exception as exc:
        if not is_known(exc):
            raise
        print(f"lessmap {args.command}: {one_line(exc)}", file=sys.stderr)
        usage = getattr(sys.modules.get("lessmap.errors"), "UsageError", None)
        return 2 if usage is not None and isinstance(exc, usage) else 1
    return code


#: How an operating-system error about a file reads, by its kind.
_FILE_ERRORS = (
    (FileNotFoundError, "no such file"),
    (IsADirectoryError, "is a folder, not a file"),
    (NotADirectoryError, "a folder on its path is a file"),
    (PermissionError, "permission denied"),
)


def one_line(exc: BaseException) -> str:
    """Return a user's error as one line: files named plainly, Zenoh's texts explained."""
    for kind, text in _FILE_ERRORS:
        if isinstance(exc, kind) and exc.filename is not None:
            return f"{exc.filename}: {text}"
    message = str(exc)
    if ".rs:" in message or "Address already in use" in message or "Unable to connect" in message:
        from lessmap_client.zenoh_errors import explain

        message = explain(message)
    return " ".join(message.split())


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

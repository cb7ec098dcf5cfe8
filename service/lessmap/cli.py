"""The ``lessmap`` command line: one entry point, one subcommand per job."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap import __version__
from lessmap.core import PROFILES, GraphError, SeedMode
from lessmap.errors import ConfigError, DatasetError
from lessmap.logfmt import configure as configure_logging
from lessmap.partition_options import add_partition_options, partition_params
from lessmap_client.adapters.replay import ReplayError
from lessmap_schemas.errors import WireError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.core import Transition

log = logging.getLogger(__name__)

#: Failures a user can fix: one line on stderr and exit code 1, no traceback.
KNOWN_EXCEPTIONS: tuple[type[Exception], ...] = (
    ConfigError,
    DatasetError,
    GraphError,
    FileNotFoundError,
    IsADirectoryError,
    PermissionError,
    ConnectionError,  # the client commands could not reach a router
    WireError,  # a frame breaks the wire contract (replay of a bad file)
    ReplayError,  # a malformed frames file given to replay
)


def _cmd_segment(args: argparse.Namespace) -> int:
    from lessmap.frames_file import read_frames
    from lessmap.offline import segment, transition_record

    params = partition_params(args)
    path = Path(args.file)
    frames = read_frames(path)
    if args.robot:
        frames = (f for f in frames if f.robot in set(args.robot))

    def emit(robot: str, transition: Transition) -> None:
        if not args.summary_only:
            print(json.dumps(transition_record(robot, transition)), flush=False)

    summary = segment(frames, params, on_transition=emit)
    record = summary.as_dict()
    record["file"] = path.name
    record["params"] = {
        "ncut_min": params.ncut_min,
        "lambda2_min": params.lambda2_min,
        "seed_mode": str(params.seed_mode),
    }
    print(json.dumps(record))
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    from lessmap.runtime.daemon import serve
    from lessmap.settings import load_settings

    flags = {
        "profile": args.profile,
        "ncut_min": args.ncut_min,
        "lambda2_min": args.lambda2_min,
        "seed_mode": args.seed_mode,
        "workers": args.workers,
        "metrics_port": args.metrics_port,
        "instance": args.instance,
        "session_idle_timeout_s": args.idle_timeout,
        "max_batch_frames": args.max_batch_frames,
        "batch_linger_ms": args.batch_linger_ms,
        **_shard_flags(args.shard),
        "mode": args.mode,
        "zenoh_config": args.zenoh_config,
        "connect": tuple(args.connect) if args.connect else None,
        "listen": tuple(args.listen) if args.listen else None,
    }
    settings = load_settings(args.config, **{k: v for k, v in flags.items() if v is not None})
    return serve(settings, args.cfg or ())


def _shard_flags(text: str | None) -> dict[str, int]:
    """Parse ``--shard I/N`` into the two settings."""
    if text is None:
        return {}
    index, sep, count = text.partition("/")
    if not sep or not index.isdigit() or not count.isdigit():
        msg = f"--shard expects I/N, e.g. 0/2, got {text!r}"
        raise ConfigError(msg)
    return {"shard_index": int(index), "shard_count": int(count)}


def _add_serve(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    srv = commands.add_parser(
        "serve",
        help="run the partition service (a Zenoh daemon for many robots)",
        description="Run the partition service in the foreground until SIGTERM/SIGINT. With no "
        "Zenoh option it opens its own router on tcp/127.0.0.1:7447. Settings come from "
        "defaults < --config FILE (JSON) < LESSMAP_* environment < these flags.",
    )
    srv.add_argument("--config", type=Path, help="JSON file of service settings")
    zen = srv.add_argument_group("Zenoh (as in zenoh-python's examples)")
    zen.add_argument("-m", "--mode", choices=["peer", "client", "router"], help="Zenoh mode")
    zen.add_argument(
        "-e",
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to connect to (repeatable), e.g. tcp/10.0.0.5:7447",
    )
    zen.add_argument(
        "-l",
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on (repeatable)",
    )
    zen.add_argument("--zenoh-config", type=Path, metavar="FILE.json5", help="Zenoh config file")
    zen.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="Zenoh config override, VALUE in JSON5 (repeatable)",
    )
    part = srv.add_argument_group("partitioning and runtime (override config and environment)")
    part.add_argument("--profile", choices=sorted(PROFILES))
    part.add_argument("--ncut-min", type=float)
    part.add_argument("--lambda2-min", type=float)
    part.add_argument("--seed-mode", choices=[m.value for m in SeedMode])
    part.add_argument("--workers", type=int, help="shards (worker threads); default 1")
    part.add_argument("--metrics-port", type=int, help="serve Prometheus /metrics on this port")
    part.add_argument("--instance", help="instance name (default: host-pid)")
    part.add_argument(
        "--shard",
        metavar="I/N",
        help="serve only the robots whose key hashes to I of N (run one instance per I)",
    )
    part.add_argument("--idle-timeout", type=float, help="seconds before an idle session closes")
    part.add_argument(
        "--max-batch-frames",
        type=int,
        help="frames coalesced per decision under load (1 = decide every frame)",
    )
    part.add_argument(
        "--batch-linger-ms",
        type=float,
        help="after waking on a quiet queue, wait this long for more frames (default 0 = off)",
    )
    srv.set_defaults(run=_cmd_serve)


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of every subcommand."""
    parser = argparse.ArgumentParser(
        prog="lessmap",
        description="Online environment segmentation for robot fleets "
        "(LESS-mapping spectral covisibility partitioning) over Eclipse Zenoh.",
    )
    parser.add_argument("--version", action="version", version=f"lessmap {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    parser.add_argument(
        "--log-format",
        choices=["text", "json"],
        default="text",
        help="stderr log lines as text or one JSON object per line (default: text)",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    seg = commands.add_parser(
        "segment",
        help="segment a recorded frames file offline (one session per robot)",
        description="Read FILE.frames.jsonl and print one JSON line per transition, then a "
        "summary line. Decides at every frame, exactly as the service does without load.",
    )
    seg.add_argument("file", metavar="FILE", help="frames file (.frames.jsonl)")
    seg.add_argument("--robot", action="append", help="only this robot (repeatable)")
    seg.add_argument("--summary-only", action="store_true", help="print only the summary")
    add_partition_options(seg)
    seg.set_defaults(run=_cmd_segment)
    _add_serve(commands)
    from lessmap.demo import add_commands as add_demo_command
    from lessmap.evaluation.commands import add_commands as add_evaluation_commands
    from lessmap.sim.command import add_command as add_sim_command
    from lessmap_client.cli_client import add_commands as add_client_commands

    add_demo_command(commands)
    add_client_commands(commands)
    add_sim_command(commands)
    add_evaluation_commands(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    # A daemon reports its lifecycle (INFO) by default; one-shot tools only warnings.
    base = logging.INFO if args.command == "serve" else logging.WARNING
    level = max(logging.DEBUG, base - 10 * args.verbose)
    configure_logging(level, args.log_format)
    try:
        code: int = args.run(args)
    except KNOWN_EXCEPTIONS as exc:
        print(f"lessmap {args.command}: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        return 0  # output piped into head & co.
    return code

"""Run the service in the foreground until SIGTERM or SIGINT (systemd-friendly)."""

from __future__ import annotations

import argparse
import gc
import logging
import signal
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh
from threadpoolctl import threadpool_limits

from lessmap.config.coexist import join_existing_router
from lessmap.config.settings import add_settings_flags, settings_from_args
from lessmap.runtime.memory import tune_allocator, use_system_malloc
from lessmap.runtime.service import Service
from lessmap.runtime.supervisor import SignalEvent
from lessmap.runtime.workers import (
    die_with_parent,
    read_worker_file,
    signal_ready,
    worker_count,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from types import FrameType

    from lessmap.cli.flags import FlagSpec
    from lessmap.config.settings import ServiceSettings

log = logging.getLogger(__name__)


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap serve``: one flag per settings field, plus --cfg."""
    parser.description = (
        "Run the partition service in the foreground until SIGTERM/SIGINT. With no Zenoh "
        "option it opens its own router on tcp/127.0.0.1:7447. Settings come from defaults "
        "< --config FILE (JSON or TOML) < LESSMAP_* environment < these flags."
    )
    specs = add_settings_flags(parser)
    parser.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="Zenoh config override, VALUE in JSON5 (repeatable)",
    )
    # Set by the parent of ``--workers N`` for each worker it starts: not for operators.
    parser.add_argument("--worker-file", type=Path, help=argparse.SUPPRESS)
    parser.set_defaults(settings_flags=specs)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap serve`` with the settings its flags, environment and file give."""
    if args.worker_file is not None:
        return _run_worker(args.worker_file, own_process=getattr(args, "own_process", False))
    specs: list[FlagSpec] = args.settings_flags
    settings = settings_from_args(args, specs)
    if getattr(args, "own_process", False):
        # Before any thread or socket: CPython's objects on glibc's malloc (a restart of this
        # process, same PID), so evicted sessions' memory can go back to the system. Only
        # when this process is the command (never replace a Python program that called us).
        # The workers of ``--workers N`` inherit the setting.
        use_system_malloc()
    # With no Zenoh option and 7447 already served (e.g. by ROS 2's rmw_zenohd): join it.
    settings = join_existing_router(settings)
    if worker_count(settings) > 1:
        from lessmap.cli.logfmt import tag_lines
        from lessmap.runtime.hub import serve_workers

        tag_lines("main")
        return serve_workers(
            settings, args.cfg or (), verbose=args.verbose, log_format=args.log_format
        )
    return serve(settings, args.cfg or ())


def _run_worker(path: Path, *, own_process: bool) -> int:
    """Run one worker of ``--workers N`` from the file its parent wrote."""
    from lessmap.cli.logfmt import tag_lines

    role, settings, zenoh_cfg = read_worker_file(path)
    tag_lines(role.tag)
    if not die_with_parent(role.parent_pid):
        log.warning("the parent (pid %d) is gone: not starting", role.parent_pid)
        return 1
    if own_process:
        use_system_malloc()
    return serve(settings, zenoh_cfg, on_ready=lambda: signal_ready(role))


def serve(
    settings: ServiceSettings,
    zenoh_cfg: Sequence[str] = (),
    on_ready: Callable[[], None] | None = None,
) -> int:
    """Start the service, park the main thread until a stop signal, stop cleanly.

    ``on_ready`` is called once the service serves (a worker tells its parent so).

    Returns:
        0 after a clean shutdown.

    Raises:
        ConfigError: the service could not start (the CLI prints one line).
    """
    # Each shard decides on its own thread; a multi-threaded BLAS under every one of them
    # oversubscribes the cores (a dense eigh went from 0.13 s to 7.9 s under load).
    with threadpool_limits(limits=1):
        return _serve(settings, zenoh_cfg, on_ready)


def _serve(
    settings: ServiceSettings, zenoh_cfg: Sequence[str], on_ready: Callable[[], None] | None
) -> int:
    # Before Zenoh starts its runtime threads (each would take a malloc arena of its own).
    log.debug("malloc options set: %s", tune_allocator() or "none")
    zenoh.init_log_from_env_or("error")
    stop = SignalEvent()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s", signal.Signals(signum).name)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    service = Service(settings, zenoh_cfg)
    # The modules and objects of start-up live as long as the process: out of the collector's
    # sight, a full collection walks only what sessions hold (docs/tuning/memory.md).
    gc.collect()
    gc.freeze()
    try:
        service.start()
        if on_ready is not None:
            on_ready()
        # Park on an Event, not on a Zenoh receive: signals are handled between waits.
        while not stop.wait(0.5):
            pass
    finally:
        service.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0

"""Run the service in the foreground until SIGTERM or SIGINT (systemd-friendly)."""

from __future__ import annotations

import gc
import logging
import signal
import threading
from typing import TYPE_CHECKING

import zenoh
from threadpoolctl import threadpool_limits

from lessmap.config.coexist import join_existing_router
from lessmap.config.settings import add_settings_flags, settings_from_args
from lessmap.runtime.memory import tune_allocator, use_system_malloc
from lessmap.runtime.service import Service

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence
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
    parser.set_defaults(settings_flags=specs)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap serve`` with the settings its flags, environment and file give."""
    specs: list[FlagSpec] = args.settings_flags
    settings = settings_from_args(args, specs)
    if getattr(args, "own_process", False):
        # Before any thread or socket: CPython's objects on glibc's malloc (a restart of this
        # process, same PID), so evicted sessions' memory can go back to the system. Only
        # when this process is the command (never replace a Python program that called us).
        use_system_malloc()
    # With no Zenoh option and 7447 already served (e.g. by ROS 2's rmw_zenohd): join it.
    return serve(join_existing_router(settings), args.cfg or ())


def serve(settings: ServiceSettings, zenoh_cfg: Sequence[str] = ()) -> int:
    """Start the service, park the main thread until a stop signal, stop cleanly.

    Returns:
        0 after a clean shutdown.

    Raises:
        ConfigError: the service could not start (the CLI prints one line).
    """
    # Each shard decides on its own thread; a multi-threaded BLAS under every one of them
    # oversubscribes the cores (a dense eigh went from 0.13 s to 7.9 s under load).
    with threadpool_limits(limits=1):
        return _serve(settings, zenoh_cfg)


def _serve(settings: ServiceSettings, zenoh_cfg: Sequence[str]) -> int:
    # Before Zenoh starts its runtime threads (each would take a malloc arena of its own).
    log.debug("malloc options set: %s", tune_allocator() or "none")
    zenoh.init_log_from_env_or("error")
    stop = threading.Event()

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
        # Park on an Event, not on a Zenoh receive: signals are handled between waits.
        while not stop.wait(0.5):
            pass
    finally:
        service.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0

"""Run a foreground command until SIGINT/SIGTERM or a duration ends."""

from __future__ import annotations

import logging
import signal
import threading
import time
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import argparse
    from collections.abc import Iterator
    from types import FrameType

log = logging.getLogger(__name__)


class StopSignal:
    """Set by SIGINT or SIGTERM (while ``stop_signals`` is active)."""

    def __init__(self) -> None:
        self.event = threading.Event()

    def wait(self, duration_s: float | None = None) -> None:
        """Return once stopped, or after ``duration_s`` seconds (None: no limit).

        Waits in short steps, so signals are handled between them.
        """
        deadline = None if duration_s is None else time.monotonic() + duration_s
        while not self.event.wait(0.2):
            if deadline is not None and time.monotonic() >= deadline:
                return


@contextmanager
def stop_signals() -> Iterator[StopSignal]:
    """Turn SIGINT and SIGTERM into a ``StopSignal`` for the block (main thread only).

    Enter it first thing in a command, so a signal during start-up still ends the command
    cleanly (exit 0) instead of killing it.
    """
    stop = StopSignal()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s", signal.Signals(signum).name)
        stop.event.set()

    in_main = threading.current_thread() is threading.main_thread()
    previous = (
        {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
        if in_main
        else {}
    )
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def add_run_options(
    parser: argparse.ArgumentParser,
    *,
    connect_timeout_s: float = 10.0,
    connect_help: str = "how long to retry while no router answers",
) -> None:
    """Add ``--duration`` and ``--connect-timeout``, the options every foreground command has."""
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after S seconds (default: run until SIGINT/SIGTERM)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=connect_timeout_s,
        metavar="S",
        help=f"{connect_help} (default {connect_timeout_s:g})",
    )

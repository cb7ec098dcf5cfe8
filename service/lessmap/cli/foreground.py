"""Run a foreground command until SIGINT/SIGTERM or a duration ends."""

from __future__ import annotations

import logging
import signal
import threading
import time
from contextlib import contextmanager
from typing import TYPE_CHECKING

from lessmap.runtime.supervisor import SignalEvent
from lessmap_client.cli_options import non_negative_float

if TYPE_CHECKING:
    import argparse
    from collections.abc import Iterator
    from types import FrameType

log = logging.getLogger(__name__)


class StopSignal:
    """Set by SIGINT or SIGTERM (while ``stop_signals`` is active)."""

    def __init__(self) -> None:
        self.event: threading.Event = SignalEvent()

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


def add_run_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--duration``, the option every foreground command has."""
    parser.add_argument(
        "--duration",
        type=non_negative_float,
        default=None,
        metavar="S",
        help="stop after S seconds (default: run until SIGINT/SIGTERM)",
    )

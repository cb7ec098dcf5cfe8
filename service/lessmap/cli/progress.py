"""Progress bars on stderr, drawn by rich only when stderr is a terminal and not ``--quiet``.

Rules of this file:

1. Nothing is drawn when stderr is not a terminal (a pipe, a file, a test's capture) or with
   ``-q/--quiet``: the command then writes exactly what it would write without this module.
2. Only stderr is drawn on; stdout is redirected through rich only when it is the terminal
   too, so piped output never passes through rich (and stays byte-identical).
3. The bars are transient: they vanish when the work is done, leaving the command's output.
"""

from __future__ import annotations

import contextlib
import sys
import threading
from typing import TYPE_CHECKING

from lessmap.progress import NO_PROGRESS, Progress

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable, Iterator
    from pathlib import Path

    import rich.progress

#: Seconds between two readings of a counter that another thread advances (``polled``).
POLL_S = 0.2


def line_count(path: Path) -> int | None:
    """Return the number of lines of a text file (the total of a bar), or None if unreadable."""
    try:
        with path.open("rb") as file:
            return sum(chunk.count(b"\n") for chunk in iter(lambda: file.read(1 << 20), b""))
    except OSError:
        return None


def wanted(args: argparse.Namespace) -> bool:
    """Return whether to draw progress: stderr is a terminal and ``--quiet`` was not given."""
    return sys.stderr.isatty() and not getattr(args, "quiet", False)


class Bars:
    """A ``Progress`` drawn as rich bars: one bar per stage, the finished ones removed."""

    def __init__(self, bars: rich.progress.Progress) -> None:
        self._bars = bars
        self._task: rich.progress.TaskID | None = None

    def stage(self, description: str, total: int | None = None) -> None:
        """Replace the current bar by one for ``description``."""
        if self._task is not None:
            self._bars.remove_task(self._task)
        self._task = self._bars.add_task(description, total=total)

    def advance(self, steps: int = 1) -> None:
        """Move the current bar on by ``steps``."""
        if self._task is not None:
            self._bars.advance(self._task, steps)

    def set_completed(self, done: int) -> None:
        """Show ``done`` steps of the current bar done."""
        if self._task is not None:
            self._bars.update(self._task, completed=done)


@contextlib.contextmanager
def progress(args: argparse.Namespace) -> Iterator[Progress]:
    """Yield a ``Progress`` that draws on stderr (rule 1), or ``NO_PROGRESS``."""
    if not wanted(args):
        yield NO_PROGRESS
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress as RichProgress,
        SpinnerColumn,
        TextColumn,
        TimeElapsedColumn,
    )

    bars = RichProgress(
        SpinnerColumn(),
        TextColumn(f"{_label(args)}{{task.description}}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=Console(stderr=True),
        transient=True,
        redirect_stdout=sys.stdout.isatty(),
    )
    with bars:
        yield Bars(bars)


def _label(args: argparse.Namespace) -> str:
    command = getattr(args, "command", None)
    return f"lessmap {command}: " if command else ""


@contextlib.contextmanager
def polled(
    shown: Progress, description: str, total: int | None, done: Callable[[], int]
) -> Iterator[None]:
    """Show ``done()`` as a stage while the block runs (work that counts on its own thread)."""
    shown.stage(description, total)
    if not isinstance(shown, Bars):
        yield
        return
    stop = threading.Event()

    def poll() -> None:
        while not stop.wait(POLL_S):
            shown.set_completed(done())

    thread = threading.Thread(target=poll, name="lessmap-progress", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()

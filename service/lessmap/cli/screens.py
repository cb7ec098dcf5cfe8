"""``lessmap watch`` and ``status`` on a terminal: rich tables; plain text everywhere else.

The commands themselves are the SDK's (``lessmap_client.cli_client``, ``.cli_status``), which
write plain, stable text: that is what a pipe, a file or a script gets, unchanged. When stdout
is a terminal, this module hands them a way to draw instead: a live rich screen for
``watch`` (redrawn in place, no escape codes of our own), rich tables for ``status``. rich is
the service's dependency, not the SDK's, so a robot's install stays small.
"""

from __future__ import annotations

import contextlib
import sys
import time
from typing import TYPE_CHECKING, Any

from lessmap_client.cli_client import configure_watch
from lessmap_client.cli_status import configure_status

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable, Iterator

    from rich.console import RenderableType

    from lessmap_client.watch import FleetView

__all__ = ["configure_status", "configure_watch", "run_status", "run_watch"]

#: Transitions listed under the table of ``watch``.
RECENT = 8


def watch_screen(view: FleetView, title: str, recent: int = RECENT) -> RenderableType:
    """Return the screen of ``watch``: title, one row per robot, the latest transitions."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    places = any(row.place is not None for row in view.rows.values())
    table = Table(header_style="bold", box=None, pad_edge=False)
    table.add_column("robot")
    table.add_column("session")
    for name in ("submap", "area", "frames", "trans", "last"):
        table.add_column(name, justify="right")
    table.add_column("reason")
    table.add_column("Ncut", justify="right")
    table.add_column("λ2", justify="right")
    if places:
        table.add_column("place")
    for (fleet, robot), row in sorted(view.rows.items()):
        cells = [
            f"{fleet}/{robot}",
            row.session,
            str(row.submap),
            str(row.area),
            _cell(row.frames),
            str(row.transitions),
            _cell(row.last_seq),
            row.last_reason,
            _cell(row.ncut, ".3f"),
            _cell(row.lambda2, ".3f"),
        ]
        table.add_row(*cells, *([row.place or "-"] if places else []), style=_style(row.open))
    elapsed_s = time.monotonic() - view.started_s
    parts: list[RenderableType] = [Text(f"{title}   ({elapsed_s:5.1f} s)", style="bold"), table]
    parts.append(Text("\nrecent transitions:", style="bold"))
    parts += [Text(f"  {line}") for line in view.log[-recent:]] or [Text("  (none yet)")]
    if view.shared_places:
        parts.append(Text("\nplaces shared by several robots (robot:area):", style="bold"))
        parts += [Text(f"  {line}") for line in view.shared_places[-recent:]]
    return Group(*parts)


@contextlib.contextmanager
def live_fleet_screen() -> Iterator[Callable[[FleetView, str], None] | None]:
    """Yield a function that redraws the fleet's screen on the terminal, or None off one."""
    if not sys.stdout.isatty():
        yield None
        return
    from rich.live import Live

    with Live(auto_refresh=False, screen=False) as live:

        def draw(view: FleetView, title: str) -> None:
            live.update(watch_screen(view, title), refresh=True)

        yield draw


def run_watch(args: argparse.Namespace) -> int:
    """Run ``lessmap watch``, drawn on a terminal."""
    from lessmap_client.cli_client import run_watch as run_plain

    with live_fleet_screen() as draw:
        return run_plain(args, draw)


def status_tables(report: dict[str, Any]) -> RenderableType:
    """Return a ``status_report`` as a rich table of instances, then its partition lines."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    from lessmap_client.cli_status import (
        STATUS_COLUMNS,
        partition_lines,
        status_notes,
        status_rows,
    )

    table = Table(header_style="bold", box=None, pad_edge=False)
    for index, name in enumerate(STATUS_COLUMNS):
        table.add_column(name, justify="left" if index < 2 else "right")
    for row, entry in zip(status_rows(report), report["instances"], strict=True):
        table.add_row(*row, style=None if "note" not in entry else "yellow")
    notes = [Text(line, style="yellow") for line in status_notes(report)]
    return Group(table, *notes, Text("\n".join(partition_lines(report))))


def run_status(args: argparse.Namespace) -> int:
    """Run ``lessmap status``, as rich tables on a terminal."""
    from lessmap_client.cli_status import run_status as run_plain

    if not sys.stdout.isatty():
        return run_plain(args)
    from rich.console import Console

    return run_plain(args, lambda report: Console().print(status_tables(report)))


def _cell(value: float | None, spec: str = "") -> str:
    return "-" if value is None else format(value, spec)


def _style(open_session: bool) -> str | None:
    return None if open_session else "dim"

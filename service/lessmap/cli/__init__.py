"""The ``lessmap`` command line: the entry point and the commands that belong to no domain."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line (``lessmap.cli.app``); return the process exit code."""
    from lessmap.cli.app import main as run

    return run(argv)

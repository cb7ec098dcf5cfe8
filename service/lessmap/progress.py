"""Progress of long work, reported to whoever runs it: the seam between a loop and a screen.

A long function takes a ``Progress`` and calls ``stage`` when it starts a part of its work
and ``advance`` as it goes; the command line passes one that draws on a terminal
(``lessmap.cli.progress``), everything else passes ``NO_PROGRESS``. No I/O here, so the
evaluation and the simulators stay free of terminals.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, TypeVar

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

T = TypeVar("T")


class Progress(Protocol):
    """Where a long function reports how far it is."""

    def stage(self, description: str, total: int | None = None) -> None:
        """Start a part of the work: ``total`` steps, or an unknown number (None)."""

    def advance(self, steps: int = 1) -> None:
        """Count ``steps`` more steps of the current part done."""


class NoProgress:
    """A ``Progress`` that reports nothing."""

    def stage(self, description: str, total: int | None = None) -> None:
        """Ignore the stage."""

    def advance(self, steps: int = 1) -> None:
        """Ignore the steps."""


NO_PROGRESS: Progress = NoProgress()


def tracked(items: Iterable[T], progress: Progress) -> Iterator[T]:
    """Yield ``items``, counting a step of the current stage as each arrives."""
    for item in items:
        progress.advance()
        yield item

"""Run a benchmark on the code of another git ref beside this tree's, in child processes.

``checkout(ref)`` makes a temporary detached worktree of ``ref`` (``git worktree add``) and
removes it afterwards; ``run_child`` runs ``python -m benchmarks.<name>`` of THIS tree with
the packages of a given tree first on ``PYTHONPATH`` (``service``, ``schemas``,
``clients/python``), so both sides run the same benchmark code and only the measured code
differs. The ref must keep the internal API the benchmark drives (compare a branch with its
base, not with a release of a year ago).
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

REPO = Path(__file__).resolve().parents[1]
_PACKAGE_DIRS = ("service", "schemas", "clients/python")


class RefRunError(RuntimeError):
    """The ref cannot be checked out, or a child run failed (the message says which)."""


def _git(*args: str) -> str:
    done = subprocess.run(
        ["git", "-C", str(REPO), *args], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        msg = f"git {' '.join(args)}: {last}"
        raise RefRunError(msg)
    return done.stdout.strip()


def describe(ref: str) -> str:
    """The ref's short commit id (raises ``RefRunError`` for an unknown ref)."""
    return _git("rev-parse", "--short", f"{ref}^{{commit}}")


@contextlib.contextmanager
def checkout(ref: str) -> Iterator[Path]:
    """A temporary detached worktree of ``ref``, removed on exit."""
    commit = describe(ref)
    folder = Path(tempfile.mkdtemp(prefix=f"lessmap-ref-{commit}-"))
    _git("worktree", "add", "--detach", "--quiet", str(folder), commit)
    try:
        yield folder
    finally:
        _git("worktree", "remove", "--force", str(folder))


def run_child(tree: Path, module: str, argv: Sequence[str]) -> dict[str, Any]:
    """Run ``python -m benchmarks.<module> ARGV --json`` on ``tree``'s packages; its JSON."""
    paths = [str(tree / folder) for folder in _PACKAGE_DIRS] + [str(REPO)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(paths))
    done = subprocess.run(
        [sys.executable, "-m", f"benchmarks.{module}", *argv, "--json"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        msg = f"benchmark on {tree} exited {done.returncode}: {last}"
        raise RefRunError(msg)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result

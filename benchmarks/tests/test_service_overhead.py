"""Smoke test of the service overhead benchmark: tiny sizes, every frame applied, JSON out.

No timing is asserted: the figures depend on the machine.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from benchmarks import service_overhead
from benchmarks.reference import REPO


def test_a_tiny_run_applies_every_frame_and_reports_each_part(
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = ["--robots", "3", "--seconds", "2", "--repeats", "1", "--json"]
    assert service_overhead.main(argv) == 0  # the worker asserts every frame was applied
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 60
    assert set(result["us_per_frame"]) == {"core", "worker", "receive"}
    assert all(value > 0 for value in result["us_per_frame"].values())


def _in_a_git_checkout() -> bool:
    done = subprocess.run(
        ["git", "-C", str(REPO), "rev-parse", "--verify", "HEAD"],
        capture_output=True,
        check=False,
    )
    return done.returncode == 0


@pytest.mark.skipif(not _in_a_git_checkout(), reason="needs a git checkout of the repository")
def test_compare_ref_runs_both_trees_and_removes_its_worktree(
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = ["--robots", "2", "--seconds", "1", "--repeats", "1", "--compare-ref", "HEAD"]
    assert service_overhead.main([*argv, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result["code"]) == {"ref", "this"}
    assert result["code"]["this"] == str(REPO / "service")
    assert result["code"]["ref"] != result["code"]["this"]  # the ref's own checkout ran
    assert all(value > 0 for value in result["ref_over_this"].values())
    checkout = Path(result["code"]["ref"]).parent  # the ref's temporary worktree
    assert not checkout.exists()
    assert str(checkout) not in _worktrees()


def _worktrees() -> str:
    # Other checkouts of the repository may come and go meanwhile: look for the ref's only.
    return subprocess.run(
        ["git", "-C", str(REPO), "worktree", "list"], capture_output=True, text=True, check=True
    ).stdout


def test_an_unknown_ref_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--robots", "2", "--seconds", "1", "--compare-ref", "no-such-ref-for-lessmap"]
    assert service_overhead.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("service_overhead: git rev-parse")
    assert err.count("\n") == 1

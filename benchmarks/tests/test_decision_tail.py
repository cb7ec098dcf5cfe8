"""Smoke test of the decision-tail benchmark: the shipped floor plan, a short tour, the table.

No timing is asserted: the figures depend on the machine.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from benchmarks import decision_tail

if TYPE_CHECKING:
    from pathlib import Path

    import pytest


def _rows(out: str) -> list[list[str]]:
    lines = [line for line in out.splitlines() if line.startswith("| example")]
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in lines]


def test_every_method_gets_a_row_beside_the_paper(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--sensors", "sparse", "--max-frames", "40", "--methods", "paper", "areas", "rooms"]
    assert decision_tail.main(argv) == 0
    rows = _rows(capsys.readouterr().out)
    assert [row[2] for row in rows] == ["paper", "areas", "rooms"]
    for row in rows:
        assert row[0] == "example sparse"
        assert int(row[3]) == 80  # two robots, 40 frames each
        p50, p99, p999, worst = (float(cell) for cell in row[5:9])
        assert 0.0 <= p50 <= p99 <= p999 <= worst
    assert rows[0][10] == "1.00 / 1.00"  # the paper against itself
    assert all("/" in row[10] for row in rows[1:])


def test_a_missing_map_is_one_line_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["--sensors", "sparse", "--floorplans", "nowhere", "--floorplan-dir", str(tmp_path)]
    assert decision_tail.main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"decision_tail: no map nowhere in {tmp_path}"

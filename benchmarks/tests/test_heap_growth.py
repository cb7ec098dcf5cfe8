from __future__ import annotations

import pytest

from benchmarks import heap_growth


def test_a_tiny_run_prints_the_heap_at_each_third_and_where_it_grew(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert heap_growth.main(["--robots", "2", "--seconds", "30", "--top", "3"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0].strip() for line in out[:3]] == ["1/3", "2/3", "end"]
    assert "600 frames" in out[2]
    assert out[3].startswith("grew most from 2/3 to end")
    assert len(out) == 4 + 3


def test_bad_sizes_are_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert heap_growth.main(["--robots", "0"]) == 2
    assert capsys.readouterr().err.startswith("heap_growth: --robots")

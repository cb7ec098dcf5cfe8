"""The results page: one command writes RESULTS.md and its figures."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import pytest

from lessmap.evaluation.markdown import ratio
from lessmap.evaluation.results import main
from tests.evaluation.helpers import write_dataset

if TYPE_CHECKING:
    from pathlib import Path

SECTIONS = (
    "## Reproduce",
    "## Where lessmap stands against the paper",
    "## rooms: information loss",
    "### Threshold sweep (LESS-mapping)",
    "## Simulated building: information loss and consistency",
    "### Consistency with the true room changes (all robots)",
    "## Why: the gap on rooms, measured",
    "### 3. e grows with the submap count: compare at equal count",
    "### 5. The absolute level depends on how H was built",
)


def test_results_page_and_figures(
    sim_frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recorded = write_dataset(tmp_path)
    out = tmp_path / "docs"
    argv = [
        "--dataset",
        str(recorded),
        "--sim",
        str(sim_frames),
        "--out",
        str(out),
        "--sweep",
        "0.25",
        "--jobs",
        "1",
    ]
    assert main(argv) == 0
    assert "wrote" in capsys.readouterr().out
    page = (out / "RESULTS.md").read_text()
    for section in SECTIONS:
        assert section in page, section
    assert f"--dataset {recorded}" in page  # the page names the command that made it
    assert "| true rooms, a submap per visit |" in page
    assert "--odometry-scale 0.01`" in page
    linked = set(re.findall(r"\(figures/([\w.]+\.png)\)", page))
    written = {path.name for path in (out / "figures").iterdir()}
    assert linked == written
    assert len(written) <= 8
    for name in written:
        data = (out / "figures" / name).read_bytes()
        assert data.startswith(b"\x89PNG")
        assert len(data) < 200_000, name


def test_results_without_the_data_set_fail_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--dataset", str(tmp_path / "none.frames.jsonl"), "--out", str(tmp_path)]) == 1
    assert capsys.readouterr().err.startswith("results: ")


@pytest.mark.parametrize(
    ("a", "b", "words"),
    [
        (2.0, 1.0, "2.0× higher than"),
        (1.0, 4.0, "4.0× lower than"),
        (1.05, 1.0, "about equal to"),
        (0.0, 0.0, "equal to"),
        (1.0, 0.0, "above"),
    ],
)
def test_ratio_words(a: float, b: float, words: str) -> None:
    assert ratio(a, b) == words

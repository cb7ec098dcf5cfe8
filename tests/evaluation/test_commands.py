"""The ``eval`` and ``plot`` subcommands, parsed and run as cli.py does."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest

from lessmap.cli import command_parser
from lessmap.errors import ConfigError, DatasetError
from lessmap.sim.simulator import simulate, write_run
from tests.evaluation.helpers import write_dataset

if TYPE_CHECKING:
    from pathlib import Path


def run(name: str, *argv: str) -> int:
    parser, run_command = command_parser(name)
    return run_command(parser.parse_args(argv))


def test_eval_prints_and_writes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    frames = write_dataset(tmp_path)
    out = tmp_path / "out"
    argv = [
        "eval",
        str(frames),
        "--out",
        str(out),
        "--plots",
        "--fixed-features",
        "5",
        "8",
        "--sweep-ncut",
        "0.1",
        "0.25",
        "--sweep-lambda2",
        "0.2",
    ]
    assert run(*argv) == 0
    text = capsys.readouterr().out
    for name in (
        "lessmap (Ncut≤0.25, λ2≤0.2)",
        "fixed-5 features",
        "fixed-8 features",
        "fixed-30 frames",
        "no partition",
        "threshold sweep",
        "wrote",
    ):
        assert name in text
    report = json.loads((out / "eval.json").read_text())
    assert [m["method"] for m in report["methods"]][1:3] == ["fixed-5 features", "fixed-8 features"]
    assert len(report["sweep"]) == 2
    assert report["information"]["unit_information_edges"] == 0
    assert (out / "eval.md").read_text().startswith("# Information loss on rooms")
    assert (out / "sweep.png").stat().st_size > 0


def test_eval_without_companions_fails_clearly(tmp_path: Path) -> None:
    frames = write_dataset(tmp_path)
    (tmp_path / "rooms.edges.jsonl").unlink()
    with pytest.raises(DatasetError, match=r"rooms\.edges\.jsonl not found"):
        run("eval", str(frames), "--no-sweep")


def test_eval_rejects_bad_options(tmp_path: Path) -> None:
    frames = write_dataset(tmp_path)
    with pytest.raises(ConfigError, match="--plots needs --out"):
        run("eval", str(frames), "--plots")
    with pytest.raises(ConfigError, match="at least 1"):
        run("eval", str(frames), "--fixed-frames", "0")
    with pytest.raises(ConfigError, match="--jobs"):
        run("eval", str(frames), "--jobs", "0")


def test_plot_without_sweep_needs_only_frames(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = write_dataset(tmp_path)
    (tmp_path / "rooms.edges.jsonl").unlink()
    assert run("plot", str(frames), "--out", str(tmp_path / "png"), "--no-sweep") == 0
    assert capsys.readouterr().out.count("wrote") == 3


def test_plot_with_sweep(tmp_path: Path) -> None:
    frames = write_dataset(tmp_path)
    argv = [
        "plot",
        str(frames),
        "--out",
        str(tmp_path / "png"),
        "--sweep-ncut",
        "0.25",
        "--sweep-lambda2",
        "0.2",
        "0.4",
    ]
    assert run(*argv) == 0
    assert (tmp_path / "png" / "sweep.png").stat().st_size > 0


def test_eval_of_a_sim_run_adds_consistency(
    sim_frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    argv = [
        "eval",
        str(sim_frames),
        "--out",
        str(out),
        "--plots",
        "--no-sweep",
        "--tolerance-frames",
        "6",
    ]
    assert run(*argv) == 0
    text = capsys.readouterr().out
    assert "robot robot0" in text  # a sim run defaults to its first robot
    assert "consistency with the ground truth" in text
    markdown = (out / "eval.md").read_text()
    assert "H synthesized from the simulator" in markdown
    assert "## Consistency with the ground truth (all robots)" in markdown
    assert "Windows ±6 frames" in markdown
    assert "| fixed-50 features |" in markdown
    assert "![consistency.png](consistency.png)" in markdown
    assert "![trajectory.png](trajectory.png)" in markdown
    assert (out / "consistency.png").read_bytes().startswith(b"\x89PNG")
    report = json.loads((out / "eval.json").read_text())
    assert [c["method"] for c in report["consistency"]][1] == "fixed-50 features"
    assert report["information"]["source"].startswith("H synthesized")


def test_eval_options_reach_the_partitioner_and_h(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = write_dataset(tmp_path)
    out = tmp_path / "out"
    argv = [
        "eval",
        str(frames),
        "--no-sweep",
        "--min-cluster-size",
        "50",
        "--min-frames-between",
        "3",
        "--odometry-scale",
        "0.5",
        "--out",
        str(out),
    ]
    assert run(*argv) == 0
    capsys.readouterr()
    report = json.loads((out / "eval.json").read_text())
    assert report["methods"][0]["submaps"] == 1  # no side of 50 features: never split
    assert report["information"]["source"].endswith("odometry information scaled by 0.5")
    markdown = (out / "eval.md").read_text()
    assert "Consistency" not in markdown  # no truth next to the file
    with pytest.raises(ConfigError, match="--odometry-scale"):
        run("eval", str(frames), "--odometry-scale", "0")
    with pytest.raises(ConfigError, match="--tolerance-frames"):
        run("eval", str(write_sim_copy(tmp_path)), "--no-sweep", "--tolerance-frames", "-1")


def write_sim_copy(folder: Path) -> Path:
    return write_run(simulate(1, rooms=2, robots=1, frames_per_robot=30), folder, "s").frames

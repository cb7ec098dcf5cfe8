"""The ``eval`` and ``plot`` subcommands, parsed and run as cli/app.py does."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest

from lessmap.cli.app import command_parser, main
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
    with pytest.raises(SystemExit) as usage:  # out of range: a wrong command line
        run("eval", str(frames), "--jobs", "0")
    assert usage.value.code == 2


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


@pytest.fixture
def area_graph(sim_frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    """The area graphs of the shared sim run, written by segment (global feature ids)."""
    out = tmp_path / "graph.json"
    argv = ["segment", "--method", "areas", "--summary-only", "--shared-features"]
    assert main([*argv, "--area-graph", str(out), str(sim_frames)]) == 0
    capsys.readouterr()
    return out


@pytest.mark.parametrize("robot", [None, "robot1"])
def test_plot_draws_an_area_graph(
    robot: str | None, area_graph: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("matplotlib", reason="lessmap plot needs the eval extra")
    figure = tmp_path / "graph.png"
    argv = ["plot", "--area-graph", str(area_graph), "--out", str(figure)]
    assert main([*argv, *(["--robot", robot] if robot else [])]) == 0
    assert capsys.readouterr().out == f"wrote {figure}\n"
    assert figure.read_bytes().startswith(b"\x89PNG")


def test_the_robot_figure_differs_from_the_fleet_figure(area_graph: Path, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="lessmap plot needs the eval extra")
    fleet, robot = tmp_path / "fleet.png", tmp_path / "robot.png"
    assert main(["plot", "--area-graph", str(area_graph), "--out", str(fleet)]) == 0
    argv = ["plot", "--area-graph", str(area_graph), "--out", str(robot), "--robot", "robot0"]
    assert main(argv) == 0
    assert fleet.read_bytes() != robot.read_bytes()


def graph_inputs(folder: Path, area_graph: Path) -> dict[str, Path]:
    broken = {
        "not json": "{",
        "a list": "[1]",
        "other format": '{"format": "x/1", "robots": {}, "fleet": {}}',
        "no fleet": '{"format": "lessmap.area_graph/1", "robots": {}}',
        "edge to nowhere": json.dumps(
            {
                "format": "lessmap.area_graph/1",
                "robots": {},
                "fleet": {
                    "nodes": [],
                    "edges": [
                        {
                            "a": 0,
                            "b": 1,
                            "a_to_b": 1,
                            "b_to_a": 0,
                            "robots": [],
                            "boundary_features": [],
                        }
                    ],
                },
            }
        ),
    }
    paths = {name: folder / f"{name.replace(' ', '_')}.json" for name in broken}
    for name, text in broken.items():
        paths[name].write_text(text, encoding="utf-8")
    return paths | {"missing": folder / "missing.json", "good": area_graph}


@pytest.mark.parametrize(
    ("case", "extra", "message"),
    [
        ("missing", [], "missing.json"),
        ("not json", [], "not JSON"),
        ("a list", [], "not an area-graph file"),
        ("other format", [], "format is 'x/1'"),
        ("no fleet", [], "missing field 'fleet'"),
        ("edge to nowhere", [], "names an area that is not a node"),
        ("good", ["--robot", "robot9"], "no robot 'robot9'; it has robot0, robot1"),
        ("good", ["FRAMES"], "not both"),
    ],
)
def test_plot_refuses_bad_area_graphs_in_one_line(
    case: str,
    extra: list[str],
    message: str,
    area_graph: Path,
    sim_frames: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    source = graph_inputs(tmp_path, area_graph)[case]
    extra = [str(sim_frames) if a == "FRAMES" else a for a in extra]
    argv = ["plot", *extra, "--area-graph", str(source), "--out", str(tmp_path / "x.png")]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("lessmap plot: ")
    assert err.count("\n") == 1
    assert message in err
    assert not (tmp_path / "x.png").exists()


def test_plot_needs_frames_or_an_area_graph(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["plot", "--out", str(tmp_path)]) == 1
    assert "give FILE (frames) or --area-graph" in capsys.readouterr().err

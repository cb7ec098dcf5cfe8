"""``lessmap rooms`` end to end, as a subprocess: files, scores and one-line errors."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lessmap.cli.app import main
from lessmap.floorplan.command import add_room_map_options, room_map_params
from lessmap.floorplan.grid import load_grid, room_labels
from lessmap.floorplan.mapfile import read_room_cells, read_room_labels
from lessmap.floorplan.metric import precision_recall
from lessmap.floorplan.roommap import RoomMapParams
from lessmap.floorplan.simcases import BenchCase, SimulatedRun, building_run


@pytest.fixture(scope="module")
def run_files(tmp_path_factory: pytest.TempPathFactory) -> SimulatedRun:
    """A generated building walked by two robots, drawn as a map with ground truth."""
    folder = tmp_path_factory.mktemp("building")
    return building_run(BenchCase(map="grid", sensor="laser270", seed=0, rate_hz=1.0), folder)


def rooms_in_process(
    capsys: pytest.CaptureFixture[str], *argv: str | Path
) -> tuple[int, list[Any], str]:
    code = main(["rooms", *map(str, argv)])
    captured = capsys.readouterr()
    return code, [json.loads(line) for line in captured.out.splitlines()], captured.err


def rooms(*argv: str | Path) -> tuple[int, list[Any], str]:
    done = subprocess.run(
        [sys.executable, "-m", "lessmap", "rooms", *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    records = [json.loads(line) for line in done.stdout.splitlines()]
    return done.returncode, records, done.stderr


def test_a_room_map_is_written_and_scored(run_files: SimulatedRun, tmp_path: Path) -> None:
    out = tmp_path / "map"
    code, [record], err = rooms(
        run_files.frames, "--map", run_files.grid_map, "--labels", run_files.labels, "-o", out
    )
    assert (code, err) == (0, "")
    assert record["robots"] == ["robot0", "robot1"]
    assert record["segmentation"] == "areas"
    assert record["benchmark"]["precision"] >= 0.9
    assert record["benchmark"]["rooms"] == 8
    # the YAML is a map_server map of the same free cells; its grey values are the rooms
    written = load_grid(Path(record["files"]["yaml"]))
    source = load_grid(run_files.grid_map)
    assert written.resolution_m == source.resolution_m
    assert written.origin_xy == source.origin_xy
    assert (written.free == source.free).all()
    labels = read_room_labels(Path(record["files"]["pgm"]))
    assert len(np.unique(labels[labels > 0])) == record["rooms"]
    assert (labels[~source.free] == 0).all()
    assert Path(record["files"]["png"]).stat().st_size > 0
    # the file of every cell's room is the map the figures score
    truth = room_labels(run_files.labels, source.resolution_m, min_room_m2=0.0)
    score = precision_recall(read_room_cells(Path(record["files"]["rooms"])), truth)
    assert round(score.precision, 4) == record["benchmark"]["precision"]
    assert round(score.recall, 4) == record["benchmark"]["recall"]


def test_one_robot_with_given_transitions(
    run_files: SimulatedRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    segmented = tmp_path / "t.jsonl"
    with segmented.open("w", encoding="utf-8") as handle:
        subprocess.run(
            [
                sys.executable,
                "-m",
                "lessmap",
                "segment",
                str(run_files.frames),
                "--method",
                "paper",
            ],
            stdout=handle,
            check=True,
            timeout=120,
        )
    given = (run_files.frames, "--map", run_files.grid_map, "--transitions", segmented)
    code, [record], err = rooms_in_process(
        capsys, *given, "--robot", "robot1", "-o", tmp_path / "one"
    )
    assert (code, err) == (0, "")
    assert record["robots"] == ["robot1"]
    assert record["segmentation"] == str(segmented)
    assert record["transitions"] > 0
    assert "benchmark" not in record
    # the flag reaches the rules (tests/floorplan/test_roommap.py shows what it changes):
    # without rule 5 no area is cut at a doorway, so there are no more rooms than with it
    code, [joined], err = rooms_in_process(
        capsys, *given, "--robot", "robot1", "--join-across-doorways", "-o", tmp_path / "joined"
    )
    assert (code, err) == (0, "")
    assert joined["rooms"] <= record["rooms"]


def test_the_benchmark_maps_read_with_their_ground_truth() -> None:
    folder = Path(__file__).resolve().parents[2] / ".." / "shared" / "floorplans"
    if not folder.is_dir():
        pytest.skip("../shared/floorplans not found (not in this checkout)")
    grid = load_grid(folder / "lab_a_scan.png")
    assert room_labels(folder / "lab_a_scan_gt_segmentation.png").shape == grid.shape


def no_pose_frames(path: Path) -> Path:
    path.write_text(
        json.dumps({"robot": "r", "seq": 0, "stamp": 0.0, "features": [1, 2], "pose": None}) + "\n",
        encoding="utf-8",
    )
    return path


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("missing_frames", "No such file"),
        ("missing_map", "no such file"),
        ("no_pose", "has no pose"),
        ("unknown_robot", "no frames of robot nobody"),
        ("bad_transitions", "not a lessmap segment transition"),
        ("wrong_labels", "the map has"),
        ("no_folder", "no folder"),
        ("bad_distance", "max_distance_m"),
        ("bad_furniture", "furniture_max_m"),
        ("map_elsewhere", "no pose lies on a free cell"),
    ],
)
def test_bad_input_gives_one_line_and_exit_1(
    run_files: SimulatedRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    case: str,
    message: str,
) -> None:
    frames, grid_map, out = run_files.frames, run_files.grid_map, tmp_path / "out"
    extra: list[str | Path] = []
    if case == "missing_frames":
        frames = tmp_path / "none.frames.jsonl"
    elif case == "missing_map":
        grid_map = tmp_path / "none.png"
    elif case == "no_pose":
        frames = no_pose_frames(tmp_path / "x.frames.jsonl")
    elif case == "unknown_robot":
        extra = ["--robot", "nobody"]
    elif case == "bad_transitions":
        bad = tmp_path / "t.jsonl"
        bad.write_text('{"robot": "robot0"}\n', encoding="utf-8")
        extra = ["--transitions", bad]
    elif case == "wrong_labels":
        small = tmp_path / "small.png"
        from PIL import Image

        Image.fromarray(np.full((30, 30), 255, dtype=np.uint8), mode="L").save(small)
        extra = ["--labels", small]
    elif case == "no_folder":
        out = tmp_path / "none" / "out"
    elif case == "bad_distance":
        extra = ["--max-distance-m", "0"]
    elif case == "bad_furniture":
        extra = ["--furniture-max-m", "-1"]
    elif case == "map_elsewhere":
        far = tmp_path / "far.yaml"
        far.write_text(
            f"image: {run_files.grid_map.with_suffix('.png').resolve()}\n"
            "resolution: 0.05\norigin: [1000.0, 1000.0, 0.0]\n",
            encoding="utf-8",
        )
        grid_map = far
    code, records, err = rooms_in_process(capsys, frames, "--map", grid_map, "-o", out, *extra)
    assert code == 1
    assert records == []
    assert err.startswith("lessmap rooms: ")
    assert message.lower() in err.lower()
    assert len(err.strip().splitlines()) == 1
    assert not out.with_suffix(".pgm").exists()


def test_the_command_reports_a_bad_file_in_one_line(run_files: SimulatedRun) -> None:
    code, records, err = rooms(run_files.frames, "--map", run_files.truth, "-o", "x")
    assert (code, records) == (1, [])
    assert err.startswith(f"lessmap rooms: {run_files.truth}: not an image")
    assert "Traceback" not in err


def test_a_missing_option_is_a_usage_error(
    run_files: SimulatedRun, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["rooms", str(run_files.frames), "-o", "x"])
    assert exited.value.code == 2
    assert "--map" in capsys.readouterr().err


def test_the_rule_switches_reach_the_room_map_parameters() -> None:
    parser = argparse.ArgumentParser()
    add_room_map_options(parser)
    defaults = room_map_params(parser.parse_args([]))
    assert defaults == RoomMapParams()
    switched = room_map_params(
        parser.parse_args(
            ["--keep-shared-regions", "--no-furniture-rooms", "--join-across-doorways"]
        )
    )
    assert switched == RoomMapParams(
        region_plurality=False, furniture_rooms=False, split_at_doorways=False
    )

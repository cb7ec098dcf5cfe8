"""``lessmap sim --floorplan`` as a user runs it: files out, one-line errors, no traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import TYPE_CHECKING

import numpy as np
import pytest
from PIL import Image

from lessmap.cli import main
from lessmap.floorplan.example import EXAMPLE_LABELS, EXAMPLE_MAP, EXAMPLE_YAML
from lessmap.floorplan.runfiles import read_floorplan_truth

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from tests.conftest import ServeProcess


def lessmap(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lessmap", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_a_run_writes_frames_that_segment_reads(tmp_path: Path) -> None:
    done = lessmap(
        "sim",
        "--floorplan",
        str(EXAMPLE_YAML),
        "--labels",
        str(EXAMPLE_LABELS),
        "--max-frames",
        "200",
        "--sensor",
        "laser360",
        "--out",
        str(tmp_path),
    )
    assert done.returncode == 0, done.stderr
    paths = json.loads(done.stdout)
    assert set(paths) == {"frames", "truth", "floorplan"}
    assert paths["frames"].endswith("example.frames.jsonl")
    assert "Traceback" not in done.stderr
    assert "400 frames" in done.stderr  # progress and the summary go to stderr
    truth = read_floorplan_truth(paths["frames"])
    assert len(truth.rows) == 400
    assert truth.sensor == "laser360"
    assert truth.document["max_frames"] == 200
    segmented = lessmap("segment", paths["frames"], "--summary-only")
    assert segmented.returncode == 0, segmented.stderr


def test_help_shows_the_defaults() -> None:
    done = lessmap("sim", "--help")
    assert done.returncode == 0
    text = " ".join(done.stdout.split())
    for expected in (
        "--floorplan MAP",
        "--labels GT.png",
        "(default: laser270)",
        "--rate HZ",
        "(default: 10.0)",
        "--speed-m M_PER_FRAME",
        "(default: 0.1)",
        "--max-frames N",
    ):
        assert expected in text, expected


def black_png(tmp_path: Path) -> str:
    path = tmp_path / "black.png"
    Image.fromarray(np.zeros((40, 40), dtype=np.uint8)).save(path)
    return str(path)


def pocket_map(tmp_path: Path) -> tuple[str, str]:
    """The example with a walled-off pocket beside it, and ground truth whose only room it is."""
    grey = np.pad(np.asarray(Image.open(EXAMPLE_MAP)), ((0, 0), (0, 40)), constant_values=205)
    grey[100:130, 445:475] = 255  # 1.5 m x 1.5 m that no robot of the building reaches
    truth = np.where(grey == 255, 0, grey).astype(np.uint8)
    truth[100:130, 445:475] = 255
    paths = (tmp_path / "pocket.png", tmp_path / "pocket_gt.png")
    Image.fromarray(grey).save(paths[0])
    Image.fromarray(truth).save(paths[1])
    return str(paths[0]), str(paths[1])


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("missing", "nope.png: no such file"),
        ("text", "not an image"),
        ("resolution", "--resolution must be above 0"),
        ("black", "no free cell"),
        ("robots", "--robots: must be at least 1"),
        ("rate", "rate must be above 0"),
        ("speed", "speed must be above 0"),
        ("labels", "gt.png: no such file"),
        ("pocket", "no room is reachable"),
        ("out", "--out must be a folder"),
    ],
)
def test_bad_input_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, message: str
) -> None:
    text = tmp_path / "notes.png"
    text.write_text("not a map", encoding="utf-8")
    base = ["sim", "--out", str(tmp_path / "out"), "--floorplan"]
    args = {
        "missing": [*base, str(tmp_path / "nope.png")],
        "text": [*base, str(text)],
        "resolution": [*base, str(EXAMPLE_MAP), "--resolution", "0"],
        "black": [*base, black_png(tmp_path)],
        "robots": [*base, str(EXAMPLE_MAP), "--robots", "0"],
        "rate": [*base, str(EXAMPLE_MAP), "--rate", "0"],
        "speed": [*base, str(EXAMPLE_MAP), "--speed-m", "0"],
        "labels": [*base, str(EXAMPLE_MAP), "--labels", str(tmp_path / "gt.png")],
    }
    if case == "out":
        args[case] = ["sim", "--out", str(text), "--floorplan", str(EXAMPLE_MAP)]
    if case == "pocket":
        args[case] = [*base, *pocket_map(tmp_path)[:1], "--labels", pocket_map(tmp_path)[1]]
    # A value out of a flag's range is a usage error (exit 2); a bad map is a failed run (1).
    if case == "robots":
        with pytest.raises(SystemExit) as usage:
            main(args[case])
        assert usage.value.code == 2
    else:
        assert main(args[case]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("lessmap sim: ")
    assert message in lines[0]
    assert not (tmp_path / "out").exists()


def test_a_bad_map_in_a_real_process_is_one_line(tmp_path: Path) -> None:
    done = lessmap("sim", "--floorplan", str(tmp_path / "nope.pgm"), "--out", str(tmp_path))
    assert done.returncode == 1
    assert done.stderr == f"lessmap sim: {tmp_path / 'nope.pgm'}: no such file\n"


def test_an_unknown_sensor_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["sim", "--floorplan", str(EXAMPLE_MAP), "--sensor", "sonar", "--out", "x"])
    assert exited.value.code == 2
    assert "invalid choice: 'sonar'" in capsys.readouterr().err


def test_publish_streams_the_tour_to_a_running_service(
    serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    service = serve()
    done = lessmap(
        "sim",
        "--floorplan",
        str(EXAMPLE_MAP),
        "--max-frames",
        "40",
        "--publish",
        "--speed",
        "20",
        "--fleet",
        fleet_name,
        "-e",
        service.endpoint,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1]) == {"published": 80, "robots": 2}
    assert "not confirmed" not in done.stderr  # the service took both robots' sessions

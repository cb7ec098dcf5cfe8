"""The floor-plan benchmark: one case in process, and its public entry point as a script."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from lessmap.floorplan.bench import main, markdown, run_bench, summarise
from lessmap.floorplan.example import EXAMPLE_DIR
from lessmap.floorplan.grid import FloorplanError, room_labels
from lessmap.floorplan.simcases import (
    BenchCase,
    FloorplanSimulator,
    SimulatedRun,
    benchmark_map,
    building_run,
    draw_building,
)
from lessmap.sim.building import generate_building


def test_one_case_scores_every_method_and_the_references(tmp_path: Path) -> None:
    case = BenchCase(map="grid", sensor="laser270", seed=1, rate_hz=1.0)
    [result] = run_bench(building_run, [case], methods=("areas", "fixed"), work_dir=tmp_path)
    assert result.case == case
    by_method = {item.method: item for item in result.results}
    assert list(by_method) == ["areas", "fixed", "truth", "geometry"]
    assert by_method["truth"].stream is None
    assert len(by_method["areas"].robot_maps) == 2  # one per robot
    areas, fixed = by_method["areas"].stream, by_method["fixed"].stream
    assert areas is not None
    assert fixed is not None
    assert areas.changes == fixed.changes > 0
    # the fixed baseline is told the true count: about as many cuts, placed blindly
    assert abs(fixed.transitions - fixed.changes) <= 2
    areas_recall = areas.figures()["boundary_recall"]
    fixed_recall = fixed.figures()["boundary_recall"]
    assert areas_recall is not None
    assert fixed_recall is not None
    assert areas_recall > fixed_recall
    truth_map = by_method["truth"].robot_maps[0]
    assert truth_map.precision > 0.95  # true labels on the walk: walls and doors respected
    assert (tmp_path / case.name / f"{case.name}.frames.jsonl").exists()
    table = markdown([result], 1.0)
    assert "| grid | areas |" in table
    assert "| all | geometry |" in table
    assert list(summarise([result])) == ["grid", "all"]


def test_a_drawn_building_has_one_ground_truth_room_per_room(tmp_path: Path) -> None:
    import random

    building = generate_building(random.Random(3), 6)
    occupancy, truth = draw_building(building)
    assert occupancy.shape == truth.shape
    assert (truth <= occupancy).all()  # the ground truth only closes doors
    path = tmp_path / "gt.png"
    Image.fromarray(truth, mode="L").save(path)
    assert room_labels(path).max() == len(building.rooms)
    assert np.count_nonzero(occupancy) > np.count_nonzero(truth)  # the doors


def test_the_benchmark_maps_are_found_by_name(tmp_path: Path) -> None:
    folder = Path(__file__).resolve().parents[2] / ".." / "shared" / "floorplans"
    if not folder.is_dir():
        pytest.skip("../shared/floorplans not found (not in this checkout)")
    image, labels = benchmark_map("office_b", folder, furnished=True)
    assert image.name == "office_b_furnitures.png"
    assert labels.name == "office_b_gt_segmentation.png"
    with pytest.raises(FloorplanError, match="office_z"):
        benchmark_map("office_z", folder)


def test_the_floorplan_simulator_runs_a_case_on_the_example_map(tmp_path: Path) -> None:
    simulator = FloorplanSimulator(EXAMPLE_DIR)
    case = BenchCase(map="example", sensor="laser270", seed=0, rate_hz=2.0)
    [result] = run_bench(simulator, [case], methods=("areas",), work_dir=tmp_path)
    areas = {item.method: item for item in result.results}["areas"]
    assert areas.stream is not None
    assert areas.stream.changes > 0
    assert areas.fleet_map.rooms == 7  # the example's seven rooms
    with pytest.raises(FloorplanError, match="unknown sensor"):
        simulator(BenchCase(map="example", sensor="sonar", seed=0, rate_hz=2.0), tmp_path)


def simulator_that_fails(case: BenchCase, folder: Path) -> SimulatedRun:
    return building_run(BenchCase(map="nowhere", sensor=case.sensor, seed=0, rate_hz=1.0), folder)


@pytest.mark.slow
def test_the_script_runs_cases_in_worker_processes(tmp_path: Path) -> None:
    out = tmp_path / "results.md"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "lessmap.floorplan.bench",
            "--maps",
            "corridor",
            "--seeds",
            "0",
            "1",
            "--rates",
            "1",
            "--methods",
            "fixed",
            "--jobs",
            "2",
            "--markdown",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("2 case(s)")
    assert out.read_text(encoding="utf-8") == done.stdout
    assert "| corridor | fixed |" in done.stdout


def test_a_bad_simulator_is_reported_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    for spec, message in [
        ("nowhere", "give building, floorplan or MODULE:FUNCTION"),
        ("lessmap.floorplan.bench:nothing", "has no attribute"),
        (f"{__name__}:simulator_that_fails", "unknown layout"),
    ]:
        assert main(["--simulator", spec, "--jobs", "1", "--seeds", "0"]) == 1
        err = capsys.readouterr().err
        assert err.startswith("lessmap.floorplan.bench: ")
        assert message in err
        assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("changes", "says"),
    [
        ({"sensor_changes": {"detection_probability": 0.7}}, "no SensorProfile field"),
        ({"tour_changes": {"turn_rate": 180.0}}, "no TourOptions field"),
        ({"speed_factor": 0.0}, "speed_factor must be > 0"),
    ],
)
def test_a_misspelt_simulator_setting_is_one_clear_error(
    changes: dict[str, Any], says: str
) -> None:
    with pytest.raises(FloorplanError, match=says):
        FloorplanSimulator(EXAMPLE_DIR, **changes)

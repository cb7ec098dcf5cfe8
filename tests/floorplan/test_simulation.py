"""Whole runs: determinism, files and their reader, sensors' feature counts, bad options."""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import numpy as np
import pytest

from lessmap.files.frames import read_frames
from lessmap.floorplan.example import EXAMPLE_LABELS, EXAMPLE_MAP
from lessmap.floorplan.grid import FloorplanError, OccupancyGrid, load_grid, room_labels
from lessmap.floorplan.options import PROFILES, FloorplanOptions, TourOptions
from lessmap.floorplan.runfiles import read_floorplan_truth, write_floorplan_run
from lessmap.floorplan.simulation import FloorplanRun, simulate_floorplan

if TYPE_CHECKING:
    from pathlib import Path

SHORT = TourOptions(max_frames=150)


@functools.cache
def grid_and_labels() -> tuple[OccupancyGrid, np.ndarray]:
    return load_grid(EXAMPLE_MAP), room_labels(EXAMPLE_LABELS)


def run(**options: object) -> FloorplanRun:
    grid, labels = grid_and_labels()
    return simulate_floorplan(grid, labels, FloorplanOptions(**options))  # type: ignore[arg-type]


def test_the_same_seed_gives_the_same_run() -> None:
    first = run(seed=4, tour=SHORT)
    again = run(seed=4, tour=SHORT)
    other = run(seed=5, tour=SHORT)
    assert first.frames == again.frames
    assert first.truth == again.truth
    assert first.frames != other.frames


def test_adding_a_robot_leaves_the_others_unchanged() -> None:
    one = run(robots=1, tour=SHORT)
    three = run(robots=3, tour=SHORT)
    assert one.frames == [f for f in three.frames if f["robot"] == "robot0"]
    assert [f["robot"] for f in three.frames[:3]] == ["robot0", "robot1", "robot2"]
    stamps = [f["stamp"] for f in three.frames]
    assert stamps == sorted(stamps)
    assert three.frames[3]["stamp"] == pytest.approx(0.1)  # seq / rate_hz


@pytest.mark.parametrize(
    ("sensor", "low", "high"),
    [("laser270", 15, 80), ("laser360", 20, 100), ("sparse", 2, 15), ("camera", 300, 1500)],
)
def test_each_sensor_sees_its_share(sensor: str, low: float, high: float) -> None:
    result = run(sensor=PROFILES[sensor], robots=1, tour=SHORT)
    counts = [len(f["features"]) for f in result.frames]
    assert low <= np.mean(counts) <= high
    assert all(f["features"] == sorted(set(f["features"])) for f in result.frames)


def test_files_round_trip(tmp_path: Path) -> None:
    grid, _ = grid_and_labels()
    result = run(tour=SHORT)
    sources = {"map": str(EXAMPLE_MAP), "labels": str(EXAMPLE_LABELS)}
    paths = write_floorplan_run(result, grid, tmp_path, "office", sources)
    frames = list(read_frames(paths.frames))
    assert [(f.robot, f.seq, list(f.features)) for f in frames] == [
        (f["robot"], f["seq"], f["features"]) for f in result.frames
    ]
    truth = read_floorplan_truth(paths.frames)
    assert list(truth.rows) == result.truth
    assert list(truth.changes) == result.room_changes
    assert truth.sensor == "laser270"
    assert truth.rooms == 7
    assert truth.labels_path == str(EXAMPLE_LABELS)
    assert truth.document["landmarks"] == result.landmarks
    assert truth.document["seed"] == 0
    first = result.truth[0]
    assert truth.positions()[(first.robot, first.seq)] == (first.x, first.y)
    assert truth.room_of()[(first.robot, first.seq)] == first.room >= 1
    assert truth.changes_of("robot1") == [c for c in result.room_changes if c.robot == "robot1"]


def test_a_broken_truth_file_is_named(tmp_path: Path) -> None:
    grid, _ = grid_and_labels()
    paths = write_floorplan_run(run(tour=SHORT), grid, tmp_path, "office", {"map": "m"})
    paths.truth.write_text('{"robot": "robot0"}\n', encoding="utf-8")
    with pytest.raises(FloorplanError, match=r"office\.truth\.jsonl:1"):
        read_floorplan_truth(paths.frames)
    with pytest.raises(FloorplanError, match="no such file"):
        read_floorplan_truth(tmp_path / "other.frames.jsonl")


def test_an_unwritable_folder_is_named(tmp_path: Path) -> None:
    grid, _ = grid_and_labels()
    blocker = tmp_path / "taken"
    blocker.write_text("a file, not a folder", encoding="utf-8")
    with pytest.raises(FloorplanError, match=r"taken.runs: cannot write \(Not a directory\)"):
        write_floorplan_run(run(tour=SHORT), grid, blocker / "runs", "office", {"map": "m"})


def test_without_labels_every_room_is_unknown() -> None:
    grid, _ = grid_and_labels()
    result = simulate_floorplan(grid, None, FloorplanOptions(robots=1, tour=SHORT))
    assert {row.room for row in result.truth} == {0}
    assert result.room_changes == []
    assert result.rooms == 0
    assert len(result.frames) == 150


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"robots": 0}, "robots must be at least 1"),
        ({"seed": -1}, "seed must be at least 0"),
        ({"tour": TourOptions(rate_hz=0.0)}, "rate must be above 0"),
        ({"tour": TourOptions(speed_m_per_frame=-0.1)}, "speed must be above 0"),
        ({"tour": TourOptions(max_frames=0)}, "max frames must be at least 1"),
    ],
)
def test_bad_options_are_refused(options: dict[str, object], message: str) -> None:
    with pytest.raises(FloorplanError, match=message):
        run(**options)


def test_labels_must_match_the_map() -> None:
    grid, labels = grid_and_labels()
    with pytest.raises(FloorplanError, match="labels are 439x280 pixels, the map 440x280"):
        simulate_floorplan(grid, labels[:, 1:], FloorplanOptions())


def test_a_map_whose_rooms_no_robot_reaches_is_refused() -> None:
    grid, labels = grid_and_labels()
    only_the_table = np.zeros_like(labels)
    only_the_table[~grid.free] = 1  # a "room" where no cell is free
    with pytest.raises(FloorplanError, match="no room is reachable"):
        simulate_floorplan(grid, only_the_table, FloorplanOptions())
    assert dataclasses.replace(FloorplanOptions(), robots=1).robots == 1

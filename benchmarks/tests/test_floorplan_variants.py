"""The floor-plan simulator variants change what they say, and only that."""

from __future__ import annotations

from dataclasses import asdict, fields
from pathlib import Path

import pytest

from benchmarks import floorplan_variants
from benchmarks.floorplan_variants import FLOORPLANS
from lessmap.files.frames import read_frames
from lessmap.floorplan.options import PROFILES, SensorProfile, TourOptions
from lessmap.floorplan.simcases import BenchCase, FloorplanSimulator

VARIANTS = {
    name: value
    for name, value in vars(floorplan_variants).items()
    if isinstance(value, FloorplanSimulator)
}


def test_each_variant_changes_one_setting_to_another_value() -> None:
    sensor_fields = {f.name for f in fields(SensorProfile)}
    tour_fields = {f.name for f in fields(TourOptions)}
    assert len(VARIANTS) == 6
    for name, variant in VARIANTS.items():
        sensor, tour = variant.sensor_changes, variant.tour_changes
        changed = len(sensor) + len(tour) + (variant.speed_factor != 1.0)
        assert changed == 1, name
        assert (variant.robots, variant.furnished) == (2, False), name
        assert set(sensor) <= sensor_fields, name
        assert set(tour) <= tour_fields, name
        for key, value in sensor.items():
            assert asdict(PROFILES["laser270"])[key] != value, name
        for key, value in tour.items():
            assert asdict(TourOptions())[key] != value, name


@pytest.mark.skipif(
    not (FLOORPLANS / "Freiburg52_scan.png").exists(),
    reason="the benchmark's floor plans (../shared/floorplans) are not here",
)
def test_fewer_detections_give_fewer_features_a_frame(tmp_path: Path) -> None:
    case = BenchCase(map="Freiburg52_scan", sensor="laser270", seed=0, rate_hz=2.0)

    def mean_features(run_dir: Path, simulator: object) -> float:
        run_dir.mkdir()
        run = simulator(case, run_dir)  # type: ignore[operator]
        sizes = [len(f.features) for f in read_frames(run.frames)]
        return sum(sizes) / len(sizes)

    default = mean_features(tmp_path / "default", FloorplanSimulator(FLOORPLANS))
    fewer = mean_features(tmp_path / "fewer", floorplan_variants.detection_07)
    assert 0.7 < fewer / default < 0.85  # 0.7 of the landmarks in view against 0.9

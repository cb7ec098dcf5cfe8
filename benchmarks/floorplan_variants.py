"""The floor-plan benchmark on other simulators: sensors and walks unlike the default ones.

    python -m lessmap.floorplan.bench --simulator benchmarks.floorplan_variants:detection_07 \
        --maps office_a office_b ... --sensors laser270 --seeds 0 --rates 10 --methods rooms areas

Run from the repository root. Results will be judged on other simulators than lessmap's, so
each variant here changes one thing the defaults were measured with (``docs/ROOMMAPS.md``,
"When the simulator changes"): a figure that holds only on the default simulator is a
figure tuned to it. The maps are the benchmark's, from ``../shared/floorplans``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lessmap.floorplan.simcases import BenchCase, SimulatedRun

FLOORPLANS = Path(__file__).resolve().parents[1] / ".." / "shared" / "floorplans"


@dataclass(frozen=True, slots=True)
class VariantSimulator:
    """The benchmark's floor-plan simulator with some sensor and walking settings changed."""

    sensor: dict[str, Any] = field(default_factory=dict)  # SensorProfile fields
    tour: dict[str, Any] = field(default_factory=dict)  # TourOptions fields
    speed_factor: float = 1.0  # times the benchmark's walking speed, at any frame rate
    folder: Path = FLOORPLANS
    furnished: bool = False

    def __call__(self, case: BenchCase, folder: Path) -> SimulatedRun:
        """Simulate ``case`` with the changed settings and write its files into ``folder``."""
        from lessmap.floorplan.grid import load_grid, room_labels
        from lessmap.floorplan.options import PROFILES, FloorplanOptions, TourOptions
        from lessmap.floorplan.runfiles import write_floorplan_run
        from lessmap.floorplan.simcases import FLOORPLAN_SPEED_MPS, SimulatedRun, benchmark_map
        from lessmap.floorplan.simulation import simulate_floorplan

        image, labels = benchmark_map(case.map, self.folder, furnished=self.furnished)
        grid = load_grid(image)
        speed_m_per_frame = FLOORPLAN_SPEED_MPS * self.speed_factor / case.rate_hz
        walk = TourOptions(rate_hz=case.rate_hz, speed_m_per_frame=speed_m_per_frame)
        options = FloorplanOptions(
            sensor=replace(PROFILES[case.sensor], **self.sensor),
            seed=case.seed,
            tour=replace(walk, **self.tour),
        )
        run = simulate_floorplan(grid, room_labels(labels, grid.resolution_m), options)
        sources = {"map": str(image), "labels": str(labels)}
        paths = write_floorplan_run(run, grid, folder, case.name, sources)
        return SimulatedRun(frames=paths.frames, truth=paths.truth, grid_map=image, labels=labels)


#: Each landmark in view is detected 7 times in 10 (the default: 9).
detection_07 = VariantSimulator(sensor={"detection_prob": 0.7})
#: 2 % of detections are reported under another landmark's id (the default: 0.5 %).
false_associations_2 = VariantSimulator(sensor={"false_association_prob": 0.02})
#: A 5 m range (the default: 8 m).
range_5m = VariantSimulator(sensor={"range_m": 5.0})
#: A landmark every 0.3 m of wall (the default: 0.5 m for the lasers).
wall_spacing_03 = VariantSimulator(sensor={"wall_spacing_m": 0.3})
#: Turns at 180 degrees a second (the default: 90).
turns_180 = VariantSimulator(tour={"turn_rate_deg_s": 180.0})
#: Half the walking speed at the same frame rate (0.05 m a frame at 10 frames a second).
half_speed = VariantSimulator(speed_factor=0.5)

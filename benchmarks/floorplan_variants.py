"""The floor-plan benchmark on other simulators: sensors and walks unlike the default ones.

    python -m lessmap.floorplan.bench --simulator benchmarks.floorplan_variants:detection_07 \
        --maps office_a office_b ... --sensors laser270 --seeds 0 --rates 10 --methods rooms areas

Run from the repository root. Results will be judged on other simulators than lessmap's, so
each variant here changes one thing the defaults were measured with (``docs/ROOMMAPS.md``,
"When the simulator changes"): a figure that holds only on the default simulator is a
figure tuned to it. The maps are the benchmark's, from ``../shared/floorplans``.
"""

from __future__ import annotations

from pathlib import Path

from lessmap.floorplan.simcases import FloorplanSimulator

FLOORPLANS = Path(__file__).resolve().parents[1] / ".." / "shared" / "floorplans"


#: Each landmark in view is detected 7 times in 10 (the default: 9).
detection_07 = FloorplanSimulator(FLOORPLANS, sensor_changes={"detection_prob": 0.7})
#: 2 % of detections are reported under another landmark's id (the default: 0.5 %).
false_associations_2 = FloorplanSimulator(
    FLOORPLANS, sensor_changes={"false_association_prob": 0.02}
)
#: A 5 m range (the default: 8 m).
range_5m = FloorplanSimulator(FLOORPLANS, sensor_changes={"range_m": 5.0})
#: A landmark every 0.3 m of wall (the default: 0.5 m for the lasers).
wall_spacing_03 = FloorplanSimulator(FLOORPLANS, sensor_changes={"wall_spacing_m": 0.3})
#: Turns at 180 degrees a second (the default: 90).
turns_180 = FloorplanSimulator(FLOORPLANS, tour_changes={"turn_rate_deg_s": 180.0})
#: Half the walking speed at the same frame rate (0.05 m a frame at 10 frames a second).
half_speed = FloorplanSimulator(FLOORPLANS, speed_factor=0.5)

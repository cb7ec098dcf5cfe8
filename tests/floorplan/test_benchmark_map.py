"""One benchmark map of the room-segmentation benchmark (skipped where ../shared is absent)."""

from __future__ import annotations

import numpy as np

from lessmap.floorplan.grid import load_grid, room_labels
from lessmap.floorplan.options import FloorplanOptions
from lessmap.floorplan.simulation import simulate_floorplan
from tests.floorplan.helpers import floorplans


def test_a_scanned_building_is_toured_room_by_room() -> None:
    folder = floorplans()
    grid = load_grid(folder / "Freiburg52_scan.png")
    labels = room_labels(folder / "Freiburg52_scan_gt_segmentation.png")
    run = simulate_floorplan(grid, labels, FloorplanOptions(robots=1))
    assert run.rooms == labels.max() >= 8
    assert len(run.rooms_visited) + len(run.rooms_skipped) == run.rooms
    assert len(run.rooms_visited) >= run.rooms - 1
    counts = np.array([len(f["features"]) for f in run.frames])
    assert counts.mean() > 10
    assert (counts > 0).mean() > 0.99
    walked_m = run.path_m["robot0"]
    per_100_m = 100.0 * len(run.room_changes) / walked_m
    assert 3.0 < per_100_m < 40.0
    assert {row.room for row in run.truth} >= set(run.rooms_visited)
    assert all(change.from_room != change.to_room for change in run.room_changes)

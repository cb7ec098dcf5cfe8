"""Small synthetic maps for the floor-plan tests, built cell by cell."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from lessmap.floorplan.grid import OccupancyGrid

REPO = Path(__file__).resolve().parents[2]
FLOORPLANS = REPO / ".." / "shared" / "floorplans"
RES = 0.05


def two_rooms(door_m: float = 1.0, wall_cells: int = 2) -> tuple[OccupancyGrid, NDArray[np.int32]]:
    """Two 4 m x 3 m rooms side by side, a wall between them with a door; and their labels.

    Room 1 is on the left (x < 4 m), room 2 on the right; the door is centred at y = 1.5 m.
    """
    room = round(4.0 / RES)
    height = round(3.0 / RES)
    free = np.zeros((height + 2, 2 * room + wall_cells + 2), dtype=bool)
    free[1:-1, 1 : 1 + room] = True
    free[1:-1, 1 + room + wall_cells : -1] = True
    door = round(door_m / RES)
    top = 1 + (height - door) // 2
    free[top : top + door, 1 + room : 1 + room + wall_cells] = door > 0
    labels = np.zeros(free.shape, dtype=np.int32)
    labels[1:-1, 1 : 1 + room] = 1
    labels[1:-1, 1 + room + wall_cells : -1] = 2
    return OccupancyGrid(free=free, resolution_m=RES), labels


def floorplans() -> Path:
    """The benchmark maps, or skip with the reason."""
    if not FLOORPLANS.is_dir():
        pytest.skip("../shared/floorplans not found (the benchmark maps are not in this checkout)")
    return FLOORPLANS

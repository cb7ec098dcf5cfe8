"""The shipped example floor plan: a small office to try the simulator on.

A 20.5 m by 12.5 m floor at 0.05 m a pixel, drawn in the benchmark's encoding: a corridor, three
offices above it (doors of 0.9, 1.0 and 1.2 m, and a door between the first two), a meeting
room below (1.6 m door), an open-plan area joined to the corridor by a 3 m opening, and a
store room off the open plan (0.8 m door); a table, a pillar and a shelf. The ground truth
draws a line across every door and the opening: seven rooms.

``python -m lessmap.floorplan.example [FOLDER]`` writes ``example.png``,
``example_gt_segmentation.png`` and ``example.yaml`` (default: the package's data folder,
where they ship).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["EXAMPLE_DIR", "EXAMPLE_LABELS", "EXAMPLE_MAP", "EXAMPLE_YAML", "draw_example"]

EXAMPLE_DIR = Path(__file__).resolve().parent / "data"
EXAMPLE_MAP = EXAMPLE_DIR / "example.png"
EXAMPLE_LABELS = EXAMPLE_DIR / "example_gt_segmentation.png"
EXAMPLE_YAML = EXAMPLE_DIR / "example.yaml"

RESOLUTION_M = 0.05
WIDTH_M, HEIGHT_M = 22.0, 14.0
FREE, UNKNOWN, WALL = 255, 205, 0

ROOMS_M = (  # x0, y0, x1, y1 of the free space of each room
    (0.75, 5.75, 21.25, 7.75),  # corridor
    (0.75, 7.9, 6.75, 13.25),  # office 1
    (6.9, 7.9, 13.75, 13.25),  # office 2
    (13.9, 7.9, 21.25, 13.25),  # office 3
    (0.75, 0.75, 7.75, 5.6),  # meeting room
    (7.9, 0.75, 21.25, 5.6),  # open plan (the store room is walled off inside it)
)
WALLS_M = ((17.35, 0.75, 17.5, 3.15), (17.35, 3.0, 21.25, 3.15))  # the store room's walls
DOORS_M = (  # openings cut through walls; the ground truth closes each with a line
    (3.0, 7.75, 3.9, 7.9),  # office 1, 0.9 m
    (9.5, 7.75, 10.5, 7.9),  # office 2, 1.0 m
    (16.0, 7.75, 17.2, 7.9),  # office 3, 1.2 m
    (6.75, 11.0, 6.9, 12.0),  # office 1 to office 2, 1.0 m
    (4.0, 5.6, 5.6, 5.75),  # meeting room, 1.6 m
    (11.0, 5.6, 14.0, 5.75),  # open plan, a 3 m opening
    (19.0, 3.0, 19.8, 3.15),  # store room, 0.8 m
)
FURNITURE_M = (
    (12.0, 1.8, 13.6, 2.6),  # table in the open plan
    (10.0, 10.5, 10.3, 10.8),  # pillar in office 2
    (20.6, 9.0, 21.25, 12.0),  # shelf in office 3
)


def _cells(box: tuple[float, float, float, float]) -> tuple[slice, slice]:
    """Pixels of a box in metres (y up, origin at the bottom-left corner)."""
    x0, y0, x1, y1 = (round(v / RESOLUTION_M) for v in box)
    rows = round(HEIGHT_M / RESOLUTION_M)
    return slice(rows - y1, rows - y0), slice(x0, x1)


def _middle_pixel(low_m: float, high_m: float) -> int:
    return (round(low_m / RESOLUTION_M) + round(high_m / RESOLUTION_M)) // 2


def draw_example() -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """The map and its ground truth, 8-bit grey (module docstring)."""
    shape = (round(HEIGHT_M / RESOLUTION_M), round(WIDTH_M / RESOLUTION_M))
    grey = np.full(shape, UNKNOWN, dtype=np.uint8)
    grey[_cells((0.6, 0.6, 21.4, 13.4))] = WALL
    for boxes, value in ((ROOMS_M, FREE), (WALLS_M, WALL), (DOORS_M, FREE), (FURNITURE_M, WALL)):
        for box in boxes:
            grey[_cells(box)] = value
    truth = grey.copy()
    for x0, y0, x1, y1 in DOORS_M:
        # A one-pixel line along the middle of the wall, from jamb to jamb.
        if x1 - x0 > y1 - y0:
            middle = _middle_pixel(y0, y1) * RESOLUTION_M
            line = (x0, middle, x1, middle + RESOLUTION_M)
        else:
            middle = _middle_pixel(x0, x1) * RESOLUTION_M
            line = (middle, y0, middle + RESOLUTION_M, y1)
        truth[_cells(line)] = WALL
    return grey, truth


def write_example(folder: Path) -> None:
    """Write the example map, its ground truth and a map_server YAML into ``folder``."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    grey, truth = draw_example()
    Image.fromarray(grey).save(folder / EXAMPLE_MAP.name, optimize=True)
    Image.fromarray(truth).save(folder / EXAMPLE_LABELS.name, optimize=True)
    (folder / EXAMPLE_YAML.name).write_text(
        f"image: {EXAMPLE_MAP.name}\n"
        f"resolution: {RESOLUTION_M}\n"
        "origin: [0.0, 0.0, 0.0]\n"
        "negate: 0\n"
        "occupied_thresh: 0.65\n"
        "free_thresh: 0.196\n",
        encoding="utf-8",
    )


if __name__ == "__main__":
    write_example(Path(sys.argv[1]) if len(sys.argv) > 1 else EXAMPLE_DIR)

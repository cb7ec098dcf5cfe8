"""Room-map files: the PGM a navigation stack loads, and the picture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lessmap.floorplan.grid import FloorplanError, OccupancyGrid, load_grid
from lessmap.floorplan.mapfile import (
    FURNITURE_SHADE,
    UNLABELLED_RGB,
    compact_labels,
    read_room_cells,
    read_room_labels,
    room_colours,
    write_room_map,
)


def furnished_room_pair() -> tuple[OccupancyGrid, np.ndarray]:
    """Two rooms (labels 9 left, 5 right) with a desk in the right one labelled 5 (rule 6)."""
    free = np.zeros((8, 12), dtype=bool)
    free[1:7, 1:6] = True
    free[1:7, 7:11] = True
    free[3:5, 8:10] = False  # the desk
    labels = np.zeros(free.shape, dtype=np.int32)
    labels[1:7, 1:6] = 9
    labels[1:7, 7:11] = 5
    labels[1, 1] = 0  # a free cell no room reached
    return OccupancyGrid(free=free, resolution_m=0.1), labels


def test_furniture_stays_occupied_in_the_pgm_and_is_shaded_in_the_picture(
    tmp_path: Path,
) -> None:
    grid, labels = furnished_room_pair()
    files = write_room_map(labels, grid, tmp_path / "rooms")
    rooms = read_room_labels(files.pgm)
    assert rooms[1, 2] == 1  # the left room's first cell comes first in raster order
    assert rooms[1, 7] == 2
    assert rooms[1, 1] == 0
    assert (rooms[3:5, 8:10] == 0).all()  # occupied, as every wall
    assert (load_grid(files.yaml).free == grid.free).all()  # navigation sees the desk
    picture = np.asarray(Image.open(files.png))
    colours = room_colours(2)
    assert (picture[1, 7] == colours[2]).all()
    shade = (colours[2] * FURNITURE_SHADE).astype(np.uint8)
    assert (picture[3:5, 8:10] == shade).all()
    assert (picture[1, 1] == UNLABELLED_RGB).all()
    assert (picture[0, 0] == 0).all()  # walls black
    # every cell's room, as scored: the desk with its room, the free cells as in the PGM
    cells = read_room_cells(files.rooms)
    assert (cells[3:5, 8:10] == 2).all()
    assert (cells[grid.free] == rooms[grid.free]).all()
    assert (cells[0] == 0).all()
    with pytest.raises(FloorplanError, match="16-bit"):
        read_room_cells(files.png)
    with pytest.raises(FloorplanError, match="no such file"):
        read_room_cells(tmp_path / "none.rooms.png")


def test_a_room_map_without_furniture_rooms_draws_none(tmp_path: Path) -> None:
    grid, labels = furnished_room_pair()
    labels[~grid.free] = 0
    files = write_room_map(labels, grid, tmp_path / "rooms")
    picture = np.asarray(Image.open(files.png))
    assert (picture[3:5, 8:10] == 0).all()
    assert (read_room_cells(files.rooms)[3:5, 8:10] == 0).all()


def test_labels_renumber_in_raster_order_and_the_limits_hold(tmp_path: Path) -> None:
    assert compact_labels(np.array([[0, 7, 7], [3, 0, 9]])).tolist() == [[0, 1, 1], [2, 0, 3]]
    grid, labels = furnished_room_pair()
    with pytest.raises(FloorplanError, match="shape"):
        write_room_map(labels[:, :-1], grid, tmp_path / "bad")
    big = OccupancyGrid(free=np.ones((16, 16), dtype=bool), resolution_m=0.1)
    with pytest.raises(FloorplanError, match="at most 254"):
        write_room_map(np.arange(256, dtype=np.int32).reshape(16, 16) + 1, big, tmp_path / "x")

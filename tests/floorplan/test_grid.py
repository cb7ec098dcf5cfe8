"""Reading maps: images, map_server YAML, the shipped example, and clear errors."""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np
import pytest
from PIL import Image

from lessmap.floorplan.example import EXAMPLE_LABELS, EXAMPLE_MAP, EXAMPLE_YAML, draw_example
from lessmap.floorplan.grid import FloorplanError, OccupancyGrid, load_grid, room_labels

if TYPE_CHECKING:
    from pathlib import Path


def test_the_shipped_example_is_what_its_script_draws() -> None:
    grey, truth = draw_example()
    assert np.array_equal(np.asarray(Image.open(EXAMPLE_MAP)), grey)
    assert np.array_equal(np.asarray(Image.open(EXAMPLE_LABELS)), truth)


def test_image_and_yaml_give_the_same_grid() -> None:
    image = load_grid(EXAMPLE_MAP)
    yaml = load_grid(EXAMPLE_YAML)
    assert image.resolution_m == yaml.resolution_m == 0.05
    assert np.array_equal(image.free, yaml.free)
    assert image.shape == (280, 440)
    # 20.5 m x 12.5 m of floor less walls and furniture.
    assert 235.0 < image.free.sum() * 0.05**2 < 256.0


def test_the_example_has_seven_rooms() -> None:
    labels = room_labels(EXAMPLE_LABELS)
    assert labels.max() == 7
    areas_m2 = np.bincount(labels.ravel())[1:] * 0.05**2
    assert areas_m2.min() > 8.0  # the store room, 3.75 m x 2.25 m


def test_cells_and_metres_round_trip() -> None:
    grid = load_grid(EXAMPLE_MAP)
    rows = np.array([0, 10, 279])
    cols = np.array([0, 300, 439])
    xy = grid.cell_to_xy(rows.astype(float), cols.astype(float))
    assert np.array_equal(grid.xy_to_cell(xy), np.stack([rows, cols], axis=-1))
    assert xy[2, 1] == pytest.approx(0.025)  # the last row is at the bottom


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "no such file"),
        (b"not a picture", "not an image"),
    ],
)
def test_bad_files_are_named(tmp_path: Path, content: bytes | None, expected: str) -> None:
    path = tmp_path / "map.png"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(FloorplanError, match=expected) as caught:
        load_grid(path)
    assert str(path) in str(caught.value)


def test_a_map_without_free_cells_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "black.png"
    Image.fromarray(np.zeros((20, 20), dtype=np.uint8)).save(path)
    with pytest.raises(FloorplanError, match="no free cell"):
        load_grid(path)


def test_a_resolution_must_be_positive() -> None:
    with pytest.raises(FloorplanError, match="resolution"):
        load_grid(EXAMPLE_MAP, resolution_m=0.0)


def test_a_yaml_without_an_image_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "map.yaml"
    path.write_text("resolution: 0.05\n", encoding="utf-8")
    with pytest.raises(FloorplanError, match="needs image and resolution"):
        load_grid(path)


def test_a_point_far_off_the_grid_is_outside_without_overflow() -> None:
    grid = OccupancyGrid(free=np.ones((4, 6), dtype=bool), resolution_m=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "invalid value encountered in cast"
        cells = grid.xy_to_cell(np.array([[1e300, -1e300], [-1e18, 1.2], [1.2, 0.7]]))
    assert cells.tolist() == [[4, 6], [1, -1], [2, 2]]

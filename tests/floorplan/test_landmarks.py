"""Landmarks on the walls: spacing, unique ids, the walkable region only, corners."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist, squareform

from lessmap.floorplan.grid import OccupancyGrid
from lessmap.floorplan.landmarks import Sites, corner_faces, thin_faces, wall_faces
from lessmap.floorplan.planner import walkable_cells
from tests.floorplan.helpers import RES, two_rooms


def box_room(width_m: float = 6.0, depth_m: float = 4.0) -> OccupancyGrid:
    free = np.zeros((round(depth_m / RES) + 2, round(width_m / RES) + 2), dtype=bool)
    free[1:-1, 1:-1] = True
    return OccupancyGrid(free=free, resolution_m=RES)


@pytest.mark.parametrize("spacing_m", [0.5, 1.0, 2.5])
def test_landmarks_keep_their_spacing_and_cover_the_walls(spacing_m: float) -> None:
    grid = box_room()
    faces = wall_faces(grid, walkable_cells(grid.free))
    assert len(faces) == 2 * (120 + 80)  # one face per wall cell side along the perimeter
    kept = faces.take(thin_faces(faces, spacing_m))
    distance = squareform(pdist(kept.xy))
    same_way = kept.normal @ kept.normal.T > 0.5
    np.fill_diagonal(distance, np.inf)
    assert distance[same_way].min() >= spacing_m - 1e-9
    # Every face has a kept one facing the same way within the spacing.
    gap = np.hypot(*(faces.xy[:, None, :] - kept.xy[None, :, :]).transpose(2, 0, 1))
    gap[faces.normal @ kept.normal.T <= 0.5] = np.inf
    assert gap.min(axis=1).max() < spacing_m
    # 20 m of wall in four straight walls: about one landmark per spacing.
    assert 20.0 / spacing_m - 4 <= len(kept) <= 20.0 / spacing_m + 8


def test_normals_point_into_the_room() -> None:
    grid = box_room()
    faces = wall_faces(grid, walkable_cells(grid.free))
    centre = np.array([3.05, 2.05])
    inward = ((centre - faces.xy) * faces.normal).sum(axis=1)
    assert (inward > 0).all()
    assert np.allclose(np.hypot(*faces.normal.T), 1.0)


def test_ids_are_unique_and_layered() -> None:
    grid = box_room()
    faces = wall_faces(grid, walkable_cells(grid.free))
    sites = Sites(faces=faces.take(thin_faces(faces, 0.5)), layers=3)
    ids = sites.ids(np.arange(len(sites.faces)))
    assert len(ids) == len(np.unique(ids)) == sites.count == 3 * len(sites.faces)
    assert ids.min() == 0
    assert ids.max() == sites.count - 1


def test_walls_of_unreachable_pockets_carry_no_landmark() -> None:
    grid = box_room(8.0, 4.0)
    free = grid.free.copy()
    free[20:40, 100:140] = False  # a solid block inside the room...
    free[25:35, 110:130] = True  # ...with a free pocket no robot reaches
    grid = OccupancyGrid(free=free, resolution_m=RES)
    walkable = walkable_cells(free)
    assert not walkable[30, 120]
    faces = wall_faces(grid, walkable)
    cells = np.stack(np.unravel_index(faces.cell, free.shape), axis=-1)
    inside_block = (
        (cells[:, 0] > 20) & (cells[:, 0] < 39) & (cells[:, 1] > 100) & (cells[:, 1] < 139)
    )
    assert not inside_block.any()


def test_the_two_sides_of_a_thin_wall_are_different_landmarks() -> None:
    grid, _ = two_rooms(door_m=1.0, wall_cells=1)
    faces = wall_faces(grid, walkable_cells(grid.free))
    kept = faces.take(thin_faces(faces, 0.5))
    wall_x = 4.0 + 1.5 * RES  # the wall column's centre
    left = kept.xy[np.isclose(kept.xy[:, 0], wall_x - RES / 2)]
    right = kept.xy[np.isclose(kept.xy[:, 0], wall_x + RES / 2)]
    assert len(left) >= 4
    assert len(right) >= 4


def test_a_rectangular_room_has_four_corners() -> None:
    grid = box_room()
    walkable = walkable_cells(grid.free)
    faces = wall_faces(grid, walkable)
    corners = faces.xy[corner_faces(grid, walkable, faces)]
    assert len(corners) == 4
    room_corners = np.array([[0.05, 0.05], [6.05, 0.05], [0.05, 4.05], [6.05, 4.05]])
    nearest = np.hypot(*(corners[:, None, :] - room_corners[None]).transpose(2, 0, 1)).min(axis=1)
    assert nearest.max() < 0.3

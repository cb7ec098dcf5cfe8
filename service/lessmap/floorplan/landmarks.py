"""Landmarks on the walls of an occupancy grid: what the simulated sensors can see.

A wall *face* is a side of an occupied cell that touches a walkable cell; its point lies on
that side, and its normal points into the free space (the gradient of the smoothed walkable
map, so a staircase of pixels along a slanted wall faces the way the wall does). Landmarks
are faces thinned to a spacing: no two of them closer than ``spacing_m`` unless they face
apart (the two sides of a thin wall are different landmarks). Corners are the maxima of the
Shi–Tomasi response of the smoothed map, snapped to their nearest face.

Invariants:
    1. Only faces of the walkable region count: walls of free pockets no robot reaches
       carry no landmark.
    2. A site may carry several landmarks (``layers``, a camera sees a wall's height);
       the ids of site ``i`` are ``i * layers .. i * layers + layers - 1``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import cKDTree

from lessmap.floorplan.grid import OccupancyGrid

__all__ = ["Faces", "Sites", "corner_faces", "thin_faces", "wall_faces"]

FACING_DOT = 0.5  # faces whose normals are within 60° of each other compete for spacing
SMOOTHING_M = 0.1  # scale of the smoothed map that gives normals and corners
CORNER_SHARE = 0.25  # a corner responds with at least this share of a right angle's response
CORNER_SPACING_M = 0.5  # at most one corner within this distance


@dataclass(frozen=True, slots=True, kw_only=True)
class Faces:
    """Sides of occupied cells that touch walkable cells, in raster order."""

    xy: NDArray[np.float64]  # (n, 2) metres, the middle of the cell side
    normal: NDArray[np.float64]  # (n, 2) unit, into the free space
    side: NDArray[np.float64]  # (n, 2) unit, the cell side's own normal (along an axis)
    cell: NDArray[np.int64]  # (n,) flat index of the occupied cell

    def __len__(self) -> int:
        return len(self.cell)

    def take(self, index: NDArray[np.int64]) -> Faces:
        """The faces at ``index``, in that order."""
        return Faces(
            xy=self.xy[index],
            normal=self.normal[index],
            side=self.side[index],
            cell=self.cell[index],
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class Sites:
    """The places landmarks sit on, each carrying ``layers`` landmark ids."""

    faces: Faces
    layers: int = 1

    @property
    def count(self) -> int:
        """Landmark ids in all (sites times layers)."""
        return len(self.faces) * self.layers

    def ids(self, sites: NDArray[np.int64]) -> NDArray[np.int64]:
        """The landmark ids of ``sites``, (len(sites) * layers,)."""
        base = np.asarray(sites, dtype=np.int64)[:, None] * self.layers
        return (base + np.arange(self.layers, dtype=np.int64)).ravel()


def wall_faces(grid: OccupancyGrid, walkable: NDArray[np.bool_]) -> Faces:
    """Every face between an occupied cell and a walkable cell (module docstring)."""
    rows, cols = grid.shape
    occupied = ~grid.free
    sigma = max(1.0, SMOOTHING_M / grid.resolution_m)
    smooth = ndimage.gaussian_filter(walkable.astype(np.float64), sigma)
    grad_row, grad_col = (np.asarray(g) for g in np.gradient(smooth))
    found: list[tuple[NDArray[np.intp], NDArray[np.intp], int, int]] = []
    for step_r, step_c in ((-1, 0), (0, -1), (0, 1), (1, 0)):
        wall = np.zeros_like(occupied)
        inner = (
            slice(max(0, -step_r), rows - max(0, step_r)),
            slice(max(0, -step_c), cols - max(0, step_c)),
        )
        outer = (
            slice(max(0, step_r), rows - max(0, -step_r)),
            slice(max(0, step_c), cols - max(0, -step_c)),
        )
        wall[inner] = occupied[inner] & walkable[outer]
        wall_r, wall_c = np.nonzero(wall)
        found.append((wall_r, wall_c, step_r, step_c))
    r = np.concatenate([f[0] for f in found])
    c = np.concatenate([f[1] for f in found])
    dr = np.concatenate([np.full(len(f[0]), f[2]) for f in found])
    dc = np.concatenate([np.full(len(f[0]), f[3]) for f in found])
    order = np.lexsort((dc, dr, c, r))
    r, c, dr, dc = r[order], c[order], dr[order], dc[order]
    xy = grid.cell_to_xy(r + 0.5 * dr, c + 0.5 * dc)
    # Normals in world axes: x along columns, y against rows; read in the free cell.
    gx = grad_col[r + dr, c + dc]
    gy = -grad_row[r + dr, c + dc]
    side = np.stack([dc, -dr], axis=-1).astype(np.float64)
    normal = np.stack([gx, gy], axis=-1)
    length = np.hypot(normal[:, 0], normal[:, 1])
    usable = (length > 1e-9) & ((normal * side).sum(axis=1) > 0)
    normal[usable] /= length[usable, None]
    normal[~usable] = side[~usable]
    return Faces(xy=xy, normal=normal, side=side, cell=r.astype(np.int64) * cols + c)


def thin_faces(faces: Faces, spacing_m: float) -> NDArray[np.int64]:
    """Indices of faces kept at ``spacing_m``: greedy in raster order (module docstring)."""
    if spacing_m <= 0:
        return np.arange(len(faces), dtype=np.int64)
    scale = 1.0 / spacing_m
    limit = spacing_m * spacing_m
    xs, ys = faces.xy[:, 0].tolist(), faces.xy[:, 1].tolist()
    nxs, nys = faces.normal[:, 0].tolist(), faces.normal[:, 1].tolist()
    buckets: dict[tuple[int, int], list[int]] = {}
    kept: list[int] = []
    for i in range(len(xs)):
        x, y, nx, ny = xs[i], ys[i], nxs[i], nys[i]
        bx, by = math.floor(x * scale), math.floor(y * scale)
        if not _crowded(buckets, bx, by, x, y, nx, ny, xs, ys, nxs, nys, limit):
            kept.append(i)
            buckets.setdefault((bx, by), []).append(i)
    return np.asarray(kept, dtype=np.int64)


def _crowded(
    buckets: dict[tuple[int, int], list[int]],
    bx: int,
    by: int,
    x: float,
    y: float,
    nx: float,
    ny: float,
    xs: list[float],
    ys: list[float],
    nxs: list[float],
    nys: list[float],
    limit: float,
) -> bool:
    for ox in (-1, 0, 1):
        for oy in (-1, 0, 1):
            for j in buckets.get((bx + ox, by + oy), ()):
                near = (xs[j] - x) ** 2 + (ys[j] - y) ** 2 < limit
                if near and nxs[j] * nx + nys[j] * ny > FACING_DOT:
                    return True
    return False


def corner_faces(
    grid: OccupancyGrid, walkable: NDArray[np.bool_], faces: Faces
) -> NDArray[np.int64]:
    """Indices of the faces nearest to the corners of the walkable region (sorted, distinct)."""
    sigma = max(1.0, SMOOTHING_M / grid.resolution_m)
    response = _min_eigenvalue(walkable.astype(np.float64), sigma)
    reference = float(_min_eigenvalue(_right_angle(sigma), sigma).max())
    window = max(3, round(CORNER_SPACING_M / grid.resolution_m))
    peaks = (response == ndimage.maximum_filter(response, size=window)) & (
        response >= CORNER_SHARE * reference
    )
    r, c = np.nonzero(peaks)
    if len(r) == 0 or len(faces) == 0:
        return np.zeros(0, dtype=np.int64)
    centres = grid.cell_to_xy(r.astype(np.float64), c.astype(np.float64))
    distance, index = cKDTree(faces.xy).query(centres)
    near = np.asarray(distance) <= 3.0 * sigma * grid.resolution_m
    return np.unique(np.asarray(index, dtype=np.int64)[near])


def _min_eigenvalue(image: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """Shi–Tomasi corner response: the smaller eigenvalue of the structure tensor."""
    smooth = ndimage.gaussian_filter(image, sigma)
    g_row, g_col = np.gradient(smooth)
    a = ndimage.gaussian_filter(g_row * g_row, 2.0 * sigma)
    b = ndimage.gaussian_filter(g_row * g_col, 2.0 * sigma)
    c = ndimage.gaussian_filter(g_col * g_col, 2.0 * sigma)
    return np.asarray(0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b))


def _right_angle(sigma: float) -> NDArray[np.float64]:
    """A free quadrant in an occupied square: the response every corner is measured against."""
    side = 2 * int(np.ceil(8 * sigma)) + 1
    image = np.zeros((side, side))
    image[side // 2 :, side // 2 :] = 1.0
    return image

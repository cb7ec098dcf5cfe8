"""Simulated sensors on an occupancy grid: which landmarks a robot sees from a pose.

A landmark site is seen when it is in range and in the field of view, faces the robot
(incidence under ``max_incidence_deg``, and the robot in front of its cell side) and the
ray to it, sampled every half cell, crosses no occupied cell other than the site's own wall
cell. Each of its landmarks is then detected with ``detection_prob``, and a detection is a
false association (another landmark's id, drawn at random) with ``false_association_prob``:
what a SLAM front end emits.

Invariants:
    1. A frame is a sorted list of distinct landmark ids.
    2. The random draws depend on the poses and the generator only, never on chunking.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from lessmap.floorplan.grid import OccupancyGrid
    from lessmap.floorplan.landmarks import Sites
    from lessmap.floorplan.options import SensorProfile

__all__ = ["detect", "visible_sites"]

_CHUNK_SAMPLES = 2_000_000  # ray samples held at once (about 50 MB of temporaries)


def visible_sites(
    grid: OccupancyGrid, sites: Sites, poses: NDArray[np.float64], profile: SensorProfile
) -> list[NDArray[np.int64]]:
    """The sites seen from each pose (x, y, theta), sorted, one array per pose.

    Args:
        grid: The map; rays are stopped by its occupied cells.
        sites: Where the landmarks are.
        poses: (n, 3) metres and radians.
        profile: Range, field of view and incidence limit.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    faces = sites.faces
    if len(faces) == 0 or len(poses) == 0:
        return [np.zeros(0, dtype=np.int64) for _ in range(len(poses))]
    tree = cKDTree(faces.xy)
    seen: list[NDArray[np.int64]] = []
    start = 0
    step = max(1, int(_CHUNK_SAMPLES // (profile.range_m / grid.resolution_m * 2.0 * 200)))
    while start < len(poses):
        chunk = poses[start : start + step]
        seen.extend(_visible_chunk(grid, sites, tree, chunk, profile))
        start += step
    return seen


def _visible_chunk(
    grid: OccupancyGrid,
    sites: Sites,
    tree: cKDTree,
    poses: NDArray[np.float64],
    profile: SensorProfile,
) -> list[NDArray[np.int64]]:
    faces = sites.faces
    pairs: Any = cKDTree(poses[:, :2]).sparse_distance_matrix(
        tree, profile.range_m, output_type="ndarray"
    )
    order = np.lexsort((pairs["j"], pairs["i"]))  # by pose, then site
    pose_of = pairs["i"][order].astype(np.int64)
    site = pairs["j"][order].astype(np.int64)
    ray = faces.xy[site] - poses[pose_of, :2]
    length = np.hypot(ray[:, 0], ray[:, 1])
    facing = -(ray * faces.normal[site]).sum(axis=1)
    keep = (length > 1e-9) & (facing > math.cos(math.radians(profile.max_incidence_deg)) * length)
    # In front of the cell side too: a ray from behind would cross the site's own cell.
    keep &= (ray * faces.side[site]).sum(axis=1) < 0
    if profile.fov_deg < 360.0:
        bearing = np.arctan2(ray[:, 1], ray[:, 0]) - poses[pose_of, 2]
        bearing = (bearing + np.pi) % (2.0 * np.pi) - np.pi
        keep &= np.abs(bearing) <= math.radians(profile.fov_deg) / 2.0
    pose_of, site, ray, length = pose_of[keep], site[keep], ray[keep], length[keep]
    clear = _unblocked(grid, poses[pose_of, :2], ray, length, faces.cell[site])
    pose_of, site = pose_of[clear], site[clear]
    bounds = np.searchsorted(pose_of, np.arange(len(poses) + 1))
    return [np.sort(site[bounds[i] : bounds[i + 1]]) for i in range(len(poses))]


def _unblocked(
    grid: OccupancyGrid,
    origin: NDArray[np.float64],
    ray: NDArray[np.float64],
    length: NDArray[np.float64],
    own_cell: NDArray[np.int64],
) -> NDArray[np.bool_]:
    """Whether each ray crosses no occupied cell but its own, sampled every half cell."""
    rows, cols = grid.shape
    res = grid.resolution_m
    steps = np.maximum(1, np.ceil(length / (0.5 * res)).astype(np.int64))
    inner = steps - 1  # samples strictly between the robot and the site
    total = int(inner.sum())
    if total == 0:
        return np.ones(len(length), dtype=bool)
    which = np.repeat(np.arange(len(length)), inner)
    first = np.cumsum(inner) - inner
    k = np.arange(total) - np.repeat(first, inner) + 1
    t = k / np.repeat(steps, inner)
    x = origin[which, 0] + t * ray[which, 0]
    y = origin[which, 1] + t * ray[which, 1]
    col = np.floor((x - grid.origin_xy[0]) / res).astype(np.int64)
    row = rows - 1 - np.floor((y - grid.origin_xy[1]) / res).astype(np.int64)
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    flat = np.where(inside, row * cols + col, 0)
    blocked = ~inside | (~grid.free.ravel()[flat] & (flat != own_cell[which]))
    hits = np.bincount(which[blocked], minlength=len(length))
    return np.asarray(hits == 0)


def detect(
    rng: np.random.Generator, sites: Sites, seen: NDArray[np.int64], profile: SensorProfile
) -> list[int]:
    """One frame: the landmarks of the sites seen, detected and (rarely) misassociated."""
    ids = sites.ids(seen)
    ids = ids[rng.random(len(ids)) < profile.detection_prob]
    wrong = rng.random(len(ids)) < profile.false_association_prob
    if wrong.any():
        ids = ids.copy()
        other = rng.integers(0, max(1, sites.count - 1), size=int(wrong.sum()))
        ids[wrong] = other + (other >= ids[wrong])  # any id but the true one
    found: list[int] = np.unique(ids).tolist()
    return found

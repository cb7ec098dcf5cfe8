"""Line of sight, field of view, detection and false associations."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lessmap.floorplan.landmarks import Sites, thin_faces, wall_faces
from lessmap.floorplan.options import PROFILES
from lessmap.floorplan.planner import walkable_cells
from lessmap.floorplan.sensors import detect, visible_sites
from tests.floorplan.helpers import two_rooms

LASER360 = PROFILES["laser360"]


def test_no_landmark_behind_a_wall_is_ever_seen() -> None:
    grid, _ = two_rooms(door_m=0.0, wall_cells=1)  # no door: the rooms are apart
    free = grid.free.copy()
    free[1:-1, 81] = True  # open the wall to make both rooms one walkable region...
    walkable = walkable_cells(free)
    faces = wall_faces(grid, walkable & grid.free)  # ...but keep it closed for the rays
    sites = Sites(faces=faces.take(thin_faces(faces, 0.1)))
    rng = np.random.default_rng(3)
    poses = np.column_stack(
        [rng.uniform(0.3, 3.8, 200), rng.uniform(0.3, 2.8, 200), rng.uniform(-3, 3, 200)]
    )
    wide = dataclasses.replace(LASER360, range_m=20.0, max_incidence_deg=89.0)
    seen = visible_sites(grid, sites, poses, wide)
    x = sites.faces.xy[:, 0]
    for visible in seen:
        assert len(visible) > 0
        assert (x[visible] <= 4.05 + 1e-9).all(), "a landmark of the other room was seen"


def test_the_far_side_of_an_open_door_is_seen() -> None:
    grid, _ = two_rooms(door_m=1.0)
    faces = wall_faces(grid, walkable_cells(grid.free))
    sites = Sites(faces=faces.take(thin_faces(faces, 0.5)))
    pose = np.array([[3.5, 1.55, 0.0]])  # facing the door from the left room
    (visible,) = visible_sites(grid, sites, pose, LASER360)
    far_wall = np.isclose(sites.faces.xy[visible, 0], 8.15)
    assert far_wall.any()


def test_the_field_of_view_is_centred_on_the_heading() -> None:
    grid, _ = two_rooms(door_m=0.0)
    faces = wall_faces(grid, walkable_cells(grid.free))
    sites = Sites(faces=faces.take(thin_faces(faces, 0.25)))
    narrow = dataclasses.replace(LASER360, fov_deg=90.0)
    for heading in (0.0, np.pi / 2, np.pi, -np.pi / 2):
        pose = np.array([[2.0, 1.5, heading]])
        (visible,) = visible_sites(grid, sites, pose, narrow)
        assert len(visible) > 0
        ray = sites.faces.xy[visible] - pose[0, :2]
        bearing = np.arctan2(ray[:, 1], ray[:, 0]) - heading
        bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
        assert np.abs(bearing).max() <= np.pi / 4 + 1e-9


def test_range_limits_what_is_seen() -> None:
    grid, _ = two_rooms(door_m=1.0)
    faces = wall_faces(grid, walkable_cells(grid.free))
    sites = Sites(faces=faces.take(thin_faces(faces, 0.25)))
    short = dataclasses.replace(LASER360, range_m=1.0)
    pose = np.array([[2.0, 1.5, 0.0]])
    (visible,) = visible_sites(grid, sites, pose, short)
    assert len(visible) == 0  # the walls are 1.5 m away or more
    (visible,) = visible_sites(grid, sites, pose, LASER360)
    distance = np.hypot(*(sites.faces.xy[visible] - pose[0, :2]).T)
    assert distance.max() <= LASER360.range_m


def test_a_frame_is_sorted_distinct_ids() -> None:
    grid, _ = two_rooms()
    faces = wall_faces(grid, walkable_cells(grid.free))
    sites = Sites(faces=faces.take(thin_faces(faces, 0.1)), layers=4)
    seen = np.arange(len(sites.faces), dtype=np.int64)
    noisy = dataclasses.replace(LASER360, false_association_prob=0.3)
    frame = detect(np.random.default_rng(0), sites, seen, noisy)
    assert frame == sorted(set(frame))
    assert all(0 <= i < sites.count for i in frame)


@pytest.mark.parametrize(("detection", "wrong"), [(1.0, 0.0), (0.9, 0.0), (0.9, 0.05)])
def test_detection_and_false_association_rates(detection: float, wrong: float) -> None:
    grid, _ = two_rooms()
    faces = wall_faces(grid, walkable_cells(grid.free))
    sites = Sites(faces=faces.take(thin_faces(faces, 0.05)))
    seen = np.arange(0, len(sites.faces), 2, dtype=np.int64)  # the even sites
    profile = dataclasses.replace(LASER360, detection_prob=detection, false_association_prob=wrong)
    rng = np.random.default_rng(1)
    found = odd = 0
    for _ in range(50):
        frame = np.asarray(detect(rng, sites, seen, profile))
        found += len(frame)
        odd += int((frame % 2 == 1).sum())
    expected = 50 * len(seen) * detection
    assert found == pytest.approx(expected, rel=0.03)
    # Half of the wrong ids land on odd (unseen) sites.
    assert odd == pytest.approx(expected * wrong / 2, abs=3 * np.sqrt(expected * wrong / 2) + 1)

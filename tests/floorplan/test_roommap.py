from __future__ import annotations

import numpy as np
import pytest

from lessmap.floorplan.furniture import FurniturePieces, furniture
from lessmap.floorplan.grid import OccupancyGrid
from lessmap.floorplan.roommap import (
    RoomMapParams,
    door_regions,
    fleet_room_map,
    label_cells,
    merge_overlapping,
    nearest_samples,
    passage_regions,
    room_map,
    split_at_doorways,
    split_at_openings,
)

RES_M = 0.1


def two_rooms(third: bool = False) -> OccupancyGrid:
    """Rooms A (cols 1-19) and B (21-39), rows 1-18, joined by a 0.4 m door at col 20.

    With ``third``, room C (cols 41-59) behind a door from B at col 40.
    """
    cols = 61 if third else 41
    free = np.zeros((20, cols), dtype=bool)
    free[1:19, 1:20] = True
    free[1:19, 21:40] = True
    free[8:12, 20] = True  # the door
    if third:
        free[1:19, 41:60] = True
        free[8:12, 40] = True
    return OccupancyGrid(free=free, resolution_m=RES_M)


def room_of_cols(grid: OccupancyGrid) -> np.ndarray:
    """The true rooms: 1 left of the door column, 2 right of it, 3 behind the second door."""
    col = np.broadcast_to(np.arange(grid.shape[1]), grid.shape)
    rooms = np.where(col < 20, 1, np.where(col <= 40, 2, 3))
    return np.where(grid.free, rooms, 0)


def walk(grid: OccupancyGrid, first_col: int, last_col: int) -> np.ndarray:
    """Poses along row 10 from one column to another, one per cell."""
    cols = np.arange(first_col, last_col + 1, dtype=float)
    return grid.cell_to_xy(np.full(cols.size, 10.0), cols)


def test_each_room_takes_the_area_of_the_poses_in_it() -> None:
    grid = two_rooms()
    xy = walk(grid, 2, 38)
    areas = np.where(xy[:, 0] < 2.0, 1, 2)  # the area changes at the door
    for regions in (None, door_regions(grid, 0.6)):
        labels = room_map(nearest_samples(grid, xy), areas, regions)
        truth = room_of_cols(grid)
        inside = truth > 0
        inside[:, 20] = False  # the door column may go either way
        assert (labels[inside] == truth[inside]).all()
        assert (labels[~grid.free] == 0).all()


def test_walls_stop_the_labels_even_where_a_room_is_nearer_through_them() -> None:
    grid = two_rooms()
    rows = np.arange(1, 19, dtype=float)
    xy = np.concatenate(
        [grid.cell_to_xy(rows, rows * 0 + 16), grid.cell_to_xy(rows, rows * 0 + 21)]
    )
    areas = np.repeat([1, 2], rows.size)
    labels = room_map(nearest_samples(grid, xy), areas)
    # cell (1, 19) is 0.2 m from B's pose (1, 21) through the wall, 0.3 m from A's (1, 16)
    assert (labels[1:7, 17:20] == 1).all()
    assert (labels[1:7, 21:24] == 2).all()


def test_a_short_excursion_does_not_split_a_room_with_regions() -> None:
    grid = two_rooms()
    xy = walk(grid, 2, 38)
    areas = np.where(xy[:, 0] < 2.4, 1, 2)  # the segmentation switched 0.3 m late, in B
    field = nearest_samples(grid, xy)
    plain = room_map(field, areas)
    snapped = room_map(field, areas, door_regions(grid, 0.6))
    in_b = room_of_cols(grid) == 2
    in_b[:, 20] = False
    assert (plain[in_b] == 1).any()  # rule 1 alone paints part of B with A's area
    assert (snapped[in_b] == 2).all()


def test_unreached_and_unvisited_cells_stay_unlabelled() -> None:
    grid = two_rooms(third=True)
    xy = walk(grid, 2, 38)  # never enters C
    areas = np.where(xy[:, 0] < 2.0, 1, 2)
    in_c = room_of_cols(grid) == 3
    far = room_map(nearest_samples(grid, xy, RoomMapParams(max_distance_m=50.0)), areas)
    assert (far[in_c] == 2).all()  # rule 1 alone: C is reachable, so B's
    regions = door_regions(grid, 0.6)
    assert (room_map(nearest_samples(grid, xy), areas, regions)[in_c] == 0).all()
    near = room_map(nearest_samples(grid, xy[:3], RoomMapParams(max_distance_m=0.5)), areas[:3])
    assert 0 < (near > 0).sum() < (room_of_cols(grid) == 1).sum()


def test_a_pose_in_a_wall_moves_to_the_nearest_free_cell_or_is_dropped() -> None:
    grid = two_rooms()
    in_wall = grid.cell_to_xy(np.array([0.0]), np.array([5.0]))  # the top wall, above (1, 5)
    field = nearest_samples(grid, in_wall)
    assert field.sample_source[0] >= 0
    assert label_cells(field, np.array([4]))[1, 5] == 4
    both = nearest_samples(grid, grid.cell_to_xy(np.array([0.0, 1.0]), np.array([5.0, 5.0])))
    assert both.source_cells.size == 1
    outside = nearest_samples(grid, np.array([[-5.0, -5.0]]))
    assert outside.sample_source[0] == -1
    assert not label_cells(outside, np.array([1])).any()


def test_poses_in_one_cell_vote_and_ties_go_to_the_smaller_area() -> None:
    grid = two_rooms()
    xy = walk(grid, 10, 10)
    field = nearest_samples(grid, np.repeat(xy, 3, axis=0))
    assert label_cells(field, np.array([5, 3, 5]))[10, 10] == 5
    assert label_cells(field, np.array([5, 3, 7]))[10, 10] == 3
    with pytest.raises(ValueError, match=">= 1"):
        label_cells(field, np.array([0, 1, 1]))
    with pytest.raises(ValueError, match="labels for"):
        label_cells(field, np.array([1]))


def test_door_regions_split_at_the_door_only() -> None:
    grid = two_rooms()
    regions = door_regions(grid, 0.6)
    assert regions.max() == 2
    assert len(np.unique(regions[room_of_cols(grid) == 1])) == 1
    assert regions[10, 5] != regions[10, 30]
    assert door_regions(grid, 0.2).max() == 1  # the door is wider: one region


def room_with(obstacle_rows: slice, obstacle_cols: slice) -> OccupancyGrid:
    """One 3.9 x 1.8 m room (rows 1-18, cols 1-39) with one obstacle standing free in it."""
    free = np.zeros((20, 41), dtype=bool)
    free[1:19, 1:40] = True
    free[obstacle_rows, obstacle_cols] = False
    return OccupancyGrid(free=free, resolution_m=RES_M)


def test_a_desk_standing_free_makes_no_doorway_a_wall_standing_free_does() -> None:
    desk = room_with(slice(7, 13), slice(18, 23))  # 0.6 x 0.5 m: 0.6 m passages beside it
    assert door_regions(desk, 0.8).max() == 2  # without the rule the desk cuts the room
    regions = door_regions(desk, 0.8, furniture_max_m=1.0)
    assert regions.max() == 1
    assert (regions[~desk.free] == 0).all()  # the desk's own cells are no room's
    assert furniture(desk, 1.0).sum() == 30
    assert furniture(desk, 0.5).sum() == 0  # 0.6 m long: longer than that
    assert furniture(desk, 0.0).sum() == 0
    wall = room_with(slice(4, 16), slice(20, 21))  # 1.2 m long, 0.3 m gaps at both ends
    assert door_regions(wall, 0.8, furniture_max_m=1.0).max() == 2
    assert door_regions(wall, 0.8, furniture_max_m=1.5).max() == 1
    # rule 5 with the stream's one area: one room around the desk, two without the rule
    xy = walk(desk, 2, 38)
    areas = np.ones(len(xy), dtype=np.int64)
    field = nearest_samples(desk, xy)
    for furniture_max_m, rooms in ((1.0, 1), (0.0, 2)):
        params = RoomMapParams(door_width_m=0.8, furniture_max_m=furniture_max_m)
        labels = room_map(field, areas, passage_regions(desk, params), params)
        assert len(np.unique(labels[desk.free])) == rooms


def test_furniture_takes_the_room_around_it_and_only_one() -> None:
    grid = two_rooms()
    free = grid.free.copy()
    free[4:7, 5:9] = False  # a desk in A
    free[9:11, 20] = False  # a post in the door, between A and B
    free[1, 30:33] = False  # a radiator on B's wall: joined to it, a wall
    grid = OccupancyGrid(free=free, resolution_m=RES_M)
    pieces = FurniturePieces.of(grid, 1.0)
    assert int(pieces.pieces.max()) == 2
    rooms = np.where(grid.free, room_of_cols(grid), 0).astype(np.int32)
    rooms[grid.free & (np.arange(41) == 20)] = 0  # the door's own cells: no room
    labelled = pieces.label(rooms)
    assert (labelled[4:7, 5:9] == 1).all()
    assert (labelled[9:11, 20] == 0).all()  # rooms 1 and 2 around it: neither
    assert (labelled[1, 30:33] == 0).all()
    assert (labelled[grid.free] == rooms[grid.free]).all()  # free cells untouched
    # cells with no room aside: a desk at the edge of what was reached still takes its room
    partly = rooms.copy()
    partly[3:8, 4:7] = 0
    assert (pieces.label(partly)[4:7, 5:9] == 1).all()
    assert (pieces.label(np.zeros_like(rooms))[~grid.free] == 0).all()
    with pytest.raises(ValueError, match="shape"):
        pieces.label(rooms[:, :-1])


def test_rule_6_labels_the_desk_with_the_room_map_and_can_be_turned_off() -> None:
    desk = room_with(slice(7, 13), slice(18, 23))
    xy = walk(desk, 2, 38)
    field = nearest_samples(desk, xy)
    areas = np.ones(len(xy), dtype=np.int64)
    for furniture_rooms, desk_label in ((True, 1), (False, 0)):
        params = RoomMapParams(door_width_m=0.8, furniture_rooms=furniture_rooms)
        labels = room_map(field, areas, passage_regions(desk, params), params)
        assert (labels[7:13, 18:23] == desk_label).all()
        assert (labels[0] == 0).all()  # walls never


def test_an_obstacle_at_the_maps_edge_is_a_wall() -> None:
    free = np.ones((10, 10), dtype=bool)
    free[0, 3:5] = False  # short, but it reaches the edge
    free[5:7, 5:7] = False
    found = furniture(OccupancyGrid(free=free, resolution_m=RES_M), 1.0)
    assert not found[0].any()
    assert found[5:7, 5:7].all()
    assert found.sum() == 4
    with pytest.raises(ValueError, match="furniture_max_m"):
        RoomMapParams(furniture_max_m=-1.0)


def test_an_area_the_stream_carried_through_a_door_becomes_two_rooms() -> None:
    grid = two_rooms()
    xy = walk(grid, 2, 38)
    areas = np.ones(len(xy), dtype=np.int64)  # the stream missed the change at the door
    regions = door_regions(grid, 0.6)
    labels = room_map(nearest_samples(grid, xy), areas, regions)
    truth = room_of_cols(grid)
    left, right = labels[truth == 1], labels[truth == 2]
    assert len(np.unique(left)) == len(np.unique(right)) == 1
    assert left[0] != right[0]
    assert {int(left[0]), int(right[0])} == {1, 2}  # the larger part keeps the area's 1
    assert len(np.unique(room_map(nearest_samples(grid, xy), areas)[grid.free])) == 1
    joined = RoomMapParams(door_width_m=0.6, split_at_doorways=False)
    assert len(np.unique(room_map(nearest_samples(grid, xy), areas, regions, joined))) == 2  # 0, 1


def test_split_at_doorways_numbers_the_smaller_parts_above_every_area() -> None:
    doorways = np.array([[1, 1, 1, 2, 2, 0, 3]], dtype=np.int32)
    labels = np.array([[4, 4, 2, 4, 2, 2, 0]], dtype=np.int32)
    out = split_at_doorways(labels, doorways)
    # area 4: two cells in region 1 (kept), one in region 2; area 2: one cell in each of
    # regions 0, 1 and 2, a tie kept by region 0; the rest numbered by (region, area)
    assert out.tolist() == [[4, 4, 5, 7, 6, 2, 0]]
    assert split_at_doorways(np.zeros((2, 2), np.int32), np.ones((2, 2), np.int32)).max() == 0


def wide_opening() -> OccupancyGrid:
    """Rooms A (cols 1-29) and B (cols 36-64), 3 m tall, joined by a 1 m wide, 0.6 m long gap."""
    free = np.zeros((32, 66), dtype=bool)
    free[1:31, 1:30] = True
    free[1:31, 36:65] = True
    free[11:21, 30:36] = True
    return OccupancyGrid(free=free, resolution_m=RES_M)


def test_wider_passages_split_two_areas_sharing_a_doorway_region() -> None:
    grid = wide_opening()
    xy = grid.cell_to_xy(np.full(60, 16.0), np.arange(3, 63, dtype=float))
    areas = np.where(xy[:, 0] < 4.0, 1, 2)  # the change decided 0.4 m into B
    doorways_only = RoomMapParams(door_width_m=0.6, wider_passages_m=(), room_opening_m=0)
    one = passage_regions(grid, doorways_only)
    assert one is not None
    assert len(one.levels) == 1
    assert door_regions(grid, 0.6).max() == 1  # the gap is wider than a door: one region
    field = nearest_samples(grid, xy)
    one_level = room_map(field, areas, one, doorways_only)
    params = RoomMapParams(door_width_m=0.6, wider_passages_m=(1.2,), room_opening_m=0)
    levels = passage_regions(grid, params)
    assert levels is not None
    assert levels.widths_m == (0.6, 1.2)
    assert len(levels.levels) == 2
    assert levels.openings is None  # rule 5 at doorways only
    labels = room_map(field, areas, levels, params)
    in_b = np.zeros(grid.shape, dtype=bool)
    in_b[1:31, 36:65] = True
    assert (one_level[in_b] == 1).any()  # rule 1: B's entrance painted with A's late area
    assert (labels[in_b] == 2).all()
    assert (labels[1:31, 1:30] == 1).all()
    assert passage_regions(grid, RoomMapParams(door_width_m=0)) is None
    with pytest.raises(ValueError, match="regions cut at"):  # regions of other widths
        room_map(field, areas, levels, RoomMapParams(door_width_m=0.6))


def test_a_room_stops_at_an_opening_when_the_part_beyond_is_a_room() -> None:
    grid = wide_opening()  # rooms of 8.4 m² each, joined by a 1 m gap: no doorway at 0.6 m
    xy = grid.cell_to_xy(np.full(60, 16.0), np.arange(3, 63, dtype=float))
    areas = np.ones(len(xy), dtype=np.int64)  # the stream missed the change
    field = nearest_samples(grid, xy)

    def labels(room_opening_m: float, min_room_m2: float = 4.0) -> np.ndarray:
        params = RoomMapParams(
            door_width_m=0.6, room_opening_m=room_opening_m, min_room_m2=min_room_m2
        )
        return room_map(field, areas, passage_regions(grid, params), params)

    split = labels(1.2)
    assert len(np.unique(split[1:31, 1:30])) == len(np.unique(split[1:31, 36:65])) == 1
    assert split[16, 10] != split[16, 50]  # A and B are two rooms
    assert len(np.unique(labels(1.2, min_room_m2=10.0)[grid.free])) == 1  # B is under 10 m²
    assert len(np.unique(labels(0.0)[grid.free])) == 1  # doorways only: one room
    params = RoomMapParams(door_width_m=0.6, wider_passages_m=())
    regions = passage_regions(grid, params)
    assert regions is not None
    assert len(regions.levels) == 1  # the doorways alone; rule 5's parts beside them
    assert regions.openings is not None
    with pytest.raises(ValueError, match="min_room_m2"):
        RoomMapParams(min_room_m2=-1.0)


def corridor_with_offices() -> tuple[OccupancyGrid, np.ndarray]:
    """A 1.6 m wide, 14 m corridor (rows 1-16), four 3 x 3 m offices below behind 1 m doors.

    Returns the grid and the true rooms (1 the corridor, 2-5 the offices).
    """
    free = np.zeros((50, 142), dtype=bool)
    truth = np.zeros(free.shape, dtype=np.int64)
    free[1:17, 1:141] = True
    truth[1:17, 1:141] = 1
    for k in range(4):
        first = 2 + 35 * k
        free[18:48, first : first + 30] = True
        truth[18:48, first : first + 30] = 2 + k
        free[17, first + 10 : first + 20] = True  # the door
    return OccupancyGrid(free=free, resolution_m=RES_M), truth


def test_a_narrow_corridor_is_not_shared_out_among_the_rooms_along_it() -> None:
    grid, truth = corridor_with_offices()
    cells = np.argwhere(truth > 0)[::7]
    xy = grid.cell_to_xy(cells[:, 0].astype(float), cells[:, 1].astype(float))
    areas = truth[cells[:, 0], cells[:, 1]]  # every room visited and named right
    params = RoomMapParams()  # doors of 1.2 m, openings of 2 m: the corridor is narrower
    regions = passage_regions(grid, params)
    assert regions is not None
    assert regions.openings is not None
    parts = regions.openings
    assert len(np.unique(parts[truth == 1])) == 1
    labels = room_map(nearest_samples(grid, xy), areas, passage_regions(grid, params), params)
    assert len(np.unique(labels[truth == 1])) == 1
    assert len(np.unique(labels[grid.free])) == 5


def test_a_corridor_named_anew_on_each_pass_is_one_room() -> None:
    grid, truth = corridor_with_offices()
    cells = np.argwhere(truth > 0)[::7]
    xy = grid.cell_to_xy(cells[:, 0].astype(float), cells[:, 1].astype(float))
    areas = truth[cells[:, 0], cells[:, 1]].copy()
    in_corridor = areas == 1
    # three passes along the corridor, each a new area: none holds 60 % of it; no wider
    # passage is tried, so no level of rule 3 decides it
    areas[in_corridor] = np.select(
        [cells[in_corridor, 1] < 60, cells[in_corridor, 1] < 100], [1, 7], 8
    )
    field = nearest_samples(grid, xy)
    params = RoomMapParams(wider_passages_m=())
    labels = room_map(field, areas, passage_regions(grid, params), params)
    corridor = labels[truth == 1]
    assert (corridor == 1).all()  # the largest area (cols 1-59) takes the whole corridor
    for office in range(2, 6):
        assert (labels[truth == office] == office).all()
    kept = RoomMapParams(wider_passages_m=(), region_plurality=False)
    pieces = room_map(field, areas, passage_regions(grid, kept), kept)
    assert {1, 7, 8} <= set(np.unique(pieces[truth == 1]))  # rule 1's labels: a piece a pass


def test_split_at_openings_keeps_small_parts_with_their_area() -> None:
    regions = np.array([[1, 1, 1, 1, 2, 2, 2, 3]], dtype=np.int32)
    labels = np.array([[5, 5, 5, 5, 5, 5, 5, 5]], dtype=np.int32)
    out = split_at_openings(labels, regions, min_cells=2)
    assert out[0, :4].tolist() == [5, 5, 5, 5]
    assert len(set(out[0, 4:7].tolist())) == 1  # 3 cells: a room of its own
    assert out[0, 4] != 5
    assert out[0, 7] == 5  # one cell: stays with its area


def test_areas_of_two_robots_that_cover_one_room_merge() -> None:
    one = np.array([[1, 1, 2, 2, 0]])
    other = np.array([[7, 7, 0, 0, 3]])  # its 7 is the first's 1; its 3 overlaps nothing
    lookups = merge_overlapping([one, other])
    assert lookups[0][1] == lookups[1][7]
    assert lookups[0][2] != lookups[0][1]
    assert lookups[1][3] not in (lookups[0][1], lookups[0][2])
    assert lookups[0][0] == lookups[1][0] == 0
    padded = merge_overlapping([one, other], top_labels=[4, 0])
    assert len(padded[0]) == 5  # label 4 has no cell but gets a fleet label
    assert padded[0][4] not in {*padded[0][1:4], *padded[1][1:]}


def test_a_fleet_map_names_a_room_once_whatever_each_robot_called_it() -> None:
    grid = two_rooms()
    xy = walk(grid, 2, 38)
    areas = np.where(xy[:, 0] < 2.0, 1, 2)
    params = RoomMapParams(door_width_m=0.6)
    regions = door_regions(grid, params.door_width_m)
    fleet = fleet_room_map(grid, [(xy, areas), (xy[::-1], 3 - areas[::-1])], params, regions)
    assert len(np.unique(fleet[room_of_cols(grid) == 1])) == 1
    assert len(np.unique(fleet[fleet > 0])) == 2
    alone = fleet_room_map(grid, [(xy, areas)], params, regions)
    assert len(np.unique(alone[alone > 0])) == 2


def test_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="region_share"):
        RoomMapParams(region_share=0.4)
    with pytest.raises(ValueError, match="max_distance_m"):
        RoomMapParams(max_distance_m=0)
    with pytest.raises(ValueError, match="door_width_m"):
        RoomMapParams(door_width_m=-1)
    with pytest.raises(ValueError, match="opening_share"):
        RoomMapParams(opening_share=1.5)
    with pytest.raises(ValueError, match="wider_passages_m"):
        RoomMapParams(wider_passages_m=(0.0,))

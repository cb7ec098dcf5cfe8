"""Ground truth of a floor-plan run: the room of every frame and the room changes.

A frame's room is the ground-truth label of the robot's cell; on a door line (label 0) or
any other unlabelled cell, the nearest labelled cell's room (Euclidean distance transform),
so stepping onto a door line is no change. A visit to another room shorter than
``flicker_m`` of path that returns to the room it came from (a robot brushing along a door
line) is no visit: those frames keep the room around them.

Invariants:
    1. The room changes are exactly the steps of the per-frame rooms.
    2. A change's ``seq`` is the first frame in the new room; x, y lie midway between that
       frame's position and the previous one (the crossing).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from lessmap.floorplan.grid import OccupancyGrid

__all__ = ["FLICKER_M", "RoomChange", "nearest_rooms", "room_changes", "rooms_along"]

FLICKER_M = 0.5


@dataclass(frozen=True, slots=True)
class RoomChange:
    """A robot entered another room: ``seq`` is its first frame there."""

    robot: str
    seq: int
    from_room: int
    to_room: int
    x: float
    y: float


def nearest_rooms(labels: NDArray[np.int32]) -> NDArray[np.int32]:
    """Every cell's room: its label, or the nearest labelled cell's (0 only without rooms)."""
    if not (labels > 0).any():
        return np.zeros_like(labels)
    index = ndimage.distance_transform_edt(labels == 0, return_distances=False, return_indices=True)
    rows, cols = np.asarray(index)
    return np.asarray(labels[rows, cols], dtype=np.int32)


def rooms_along(
    grid: OccupancyGrid,
    rooms: NDArray[np.int32],
    poses: NDArray[np.float64],
    flicker_m: float = FLICKER_M,
) -> NDArray[np.int32]:
    """The room of each pose (module docstring), shape (n,)."""
    if len(poses) == 0:
        return np.zeros(0, dtype=np.int32)
    cells = grid.xy_to_cell(poses[:, :2])
    rows = np.clip(cells[:, 0], 0, grid.shape[0] - 1)
    cols = np.clip(cells[:, 1], 0, grid.shape[1] - 1)
    along = rooms[rows, cols].copy()
    step_m = np.concatenate([[0.0], np.hypot(*np.diff(poses[:, :2], axis=0).T)])
    starts = np.flatnonzero(np.concatenate([[True], along[1:] != along[:-1]]))
    ends = np.concatenate([starts[1:], [len(along)]])
    for i in range(1, len(starts) - 1):
        before, run, after = along[starts[i - 1]], slice(starts[i], ends[i]), along[ends[i]]
        # Path walked inside the run: from its first step in to its first step out.
        walked_m = float(step_m[starts[i] + 1 : ends[i] + 1].sum())
        if before == after and walked_m < flicker_m:
            along[run] = before
    return along


def room_changes(
    robot: str, rooms: NDArray[np.int32], poses: NDArray[np.float64]
) -> list[RoomChange]:
    """The steps of ``rooms`` (one robot's frames, seq = index), with where they happened."""
    steps = np.flatnonzero(rooms[1:] != rooms[:-1]) + 1
    changes = []
    for seq in steps.tolist():
        x, y = 0.5 * (poses[seq - 1, :2] + poses[seq, :2])
        changes.append(
            RoomChange(
                robot,
                seq,
                int(rooms[seq - 1]),
                int(rooms[seq]),
                round(float(x), 4),
                round(float(y), 4),
            )
        )
    return changes

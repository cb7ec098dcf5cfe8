"""Furniture in an occupancy grid: obstacles standing free inside rooms.

``furniture`` finds them: rule 3 treats them as floor (a desk narrows no doorway).
``FurniturePieces`` gives each piece the room around it (rule 6 of
``lessmap.floorplan.roommap``): the floor under a desk is the office's, and the benchmark's
ground truth counts it so, while a map of free cells alone would leave it unlabelled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from lessmap.floorplan.pairs import unique_pairs

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from lessmap.floorplan.grid import OccupancyGrid

__all__ = ["FurniturePieces", "furniture"]

EIGHT = np.ones((3, 3), dtype=bool)


def _pieces(grid: OccupancyGrid, max_length_m: float) -> NDArray[np.int32]:
    """Each furniture cell's piece (1..k, 8-connected), 0 elsewhere."""
    occupied = ~grid.free
    if max_length_m <= 0 or not occupied.any():
        return np.zeros(occupied.shape, dtype=np.int32)
    labels, count = ndimage.label(occupied, structure=EIGHT)
    short = np.zeros(count + 1, dtype=bool)
    longest = max_length_m / grid.resolution_m
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is not None:
            short[index] = max(box[0].stop - box[0].start, box[1].stop - box[1].start) <= longest
    short[np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])] = False
    short[0] = False
    kept = np.flatnonzero(short)
    number = np.zeros(count + 1, dtype=np.int32)
    number[kept] = np.arange(1, kept.size + 1, dtype=np.int32)
    out: NDArray[np.int32] = number[labels]
    return out


def furniture(grid: OccupancyGrid, max_length_m: float) -> NDArray[np.bool_]:
    """Occupied cells of free-standing obstacles no longer than ``max_length_m``.

    An obstacle is an 8-connected set of occupied cells; it stands free when it touches no
    wall (walls join up into long structures reaching the map's edge, so a short obstacle
    not at the edge is a table, a chair or a cabinet). Its length is its bounding box's
    longer side. ``max_length_m`` 0: none.
    """
    out: NDArray[np.bool_] = _pieces(grid, max_length_m) > 0
    return out


@dataclass(frozen=True, slots=True)
class FurniturePieces:
    """The grid's furniture pieces and the free cells around each (one per map).

    ``label(rooms)`` gives a piece the room of the free cells around it when they name
    exactly one room (cells with no room aside): a chair between two rooms' cells, or at
    the edge of what a robot reached and something else, keeps 0.
    """

    pieces: NDArray[np.int32]  # (rows, cols): each furniture cell's piece, 0 elsewhere
    ring_piece: NDArray[np.int64]  # (m,) a piece ...
    ring_cell: NDArray[np.int64]  # (m,) ... and the flat index of a free cell touching it
    count: int  # pieces 1..count

    @classmethod
    def of(cls, grid: OccupancyGrid, max_length_m: float) -> FurniturePieces:
        """Find the pieces (``furniture``'s obstacles) and their free neighbours (8-way)."""
        pieces = _pieces(grid, max_length_m)
        rows, cols = pieces.shape
        flat = np.arange(pieces.size, dtype=np.int64).reshape(pieces.shape)
        ring_piece, ring_cell = [], []
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr == dc == 0:
                    continue
                # a cell of the piece at (r, c) and its neighbour at (r + dr, c + dc)
                here = (
                    slice(max(0, -dr), rows - max(0, dr)),
                    slice(max(0, -dc), cols - max(0, dc)),
                )
                there = (slice(max(0, dr), rows + min(0, dr)), slice(max(0, dc), cols + min(0, dc)))
                touch = (pieces[here] > 0) & grid.free[there]
                ring_piece.append(pieces[here][touch].astype(np.int64))
                ring_cell.append(flat[there][touch])
        pairs, _, _ = unique_pairs(np.concatenate(ring_piece), np.concatenate(ring_cell))
        return cls(pieces, pairs[:, 0].copy(), pairs[:, 1].copy(), int(pieces.max(initial=0)))

    def label(self, rooms: NDArray[np.int32]) -> NDArray[np.int32]:
        """Rule 6: each piece the free cells around name one room of gets that room."""
        if rooms.shape != self.pieces.shape:
            msg = f"rooms of shape {rooms.shape} for a grid of shape {self.pieces.shape}"
            raise ValueError(msg)
        around = rooms.ravel()[self.ring_cell]
        named = around > 0
        pairs, _, _ = unique_pairs(self.ring_piece[named], around[named])
        rooms_around = np.bincount(pairs[:, 0], minlength=self.count + 1)
        room_of_piece = np.zeros(self.count + 1, dtype=np.int32)
        single = pairs[rooms_around[pairs[:, 0]] == 1]
        room_of_piece[single[:, 0]] = single[:, 1]
        take = room_of_piece[self.pieces]
        return np.where((take > 0) & (rooms == 0), take, rooms).astype(np.int32)

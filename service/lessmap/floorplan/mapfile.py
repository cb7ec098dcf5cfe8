"""Room-map files: a labelled map that ROS map_server loads as an occupancy map, and a picture.

``write_room_map(labels, grid, stem)`` writes:

- ``<stem>.pgm``: 8-bit grey, row 0 at the top: room 1..254 on a labelled free cell, 0 on a
  free cell without a room, 255 on an occupied one (rooms renumbered in raster order).
- ``<stem>.yaml``: map_server's ``image``, ``resolution``, ``origin``, ``negate: 1``,
  ``occupied_thresh: 0.999``, ``free_thresh: 0.998``, ``mode: trinary``. Negated, the
  occupancy is grey / 255: every free cell reads free, every wall occupied, so the file is
  a navigation map whose grey values are the rooms. ``load_grid`` reads it back, and
  ``read_room_labels`` its rooms.
- ``<stem>.png``: walls black, free cells without a room light grey, a colour per room,
  furniture given a room (rule 6 of ``lessmap.floorplan.roommap``) in a darker shade of it.
- ``<stem>.rooms.png``: 16-bit grey, every cell's room numbered as in the PGM, furniture
  included, 0 none: the room map as scored (``read_room_cells``).

The PGM keeps furniture occupied whatever its room: a navigation map must not read a desk
as floor, so the furniture's rooms are in the other two files.
"""

from __future__ import annotations

import colorsys
import os
from contextlib import contextmanager
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from lessmap.floorplan.grid import FloorplanError, read_image

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from numpy.typing import NDArray

    from lessmap.floorplan.grid import OccupancyGrid

__all__ = [
    "MAX_LABELS",
    "RoomMapFiles",
    "compact_labels",
    "read_room_cells",
    "read_room_labels",
    "write_room_map",
]

MAX_LABELS = 254
OCCUPIED_GREY = 255
UNLABELLED_RGB = (230, 230, 230)
FURNITURE_SHADE = 0.6  # furniture in the picture: its room's colour, this much as bright


class RoomMapFiles(NamedTuple):
    """The files ``write_room_map`` wrote."""

    pgm: Path
    yaml: Path
    png: Path
    rooms: Path  # every cell's room, furniture included


def compact_labels(labels: NDArray[np.integer]) -> NDArray[np.int32]:
    """Renumber the labels 1..k in raster order of their first cell (0 stays 0)."""
    flat = np.asarray(labels).ravel()
    ids, first, inverse = np.unique(flat, return_index=True, return_inverse=True)
    nonzero = np.flatnonzero(ids != 0)
    ranked = nonzero[np.argsort(first[nonzero], kind="stable")]
    number = np.zeros(ids.size, dtype=np.int32)
    number[ranked] = np.arange(1, ranked.size + 1, dtype=np.int32)
    out = number[inverse.reshape(-1)]
    return out.reshape(np.shape(labels))


def room_colours(count: int) -> NDArray[np.uint8]:
    """``count`` + 1 RGB colours: index 0 unused, then distinct hues (golden-ratio steps)."""
    colours = np.zeros((count + 1, 3), dtype=np.uint8)
    for index in range(1, count + 1):
        hue = (index * 0.618033988749895) % 1.0
        value = 0.95 if index % 2 else 0.75
        r, g, b = colorsys.hsv_to_rgb(hue, 0.65, value)
        colours[index] = (round(255 * r), round(255 * g), round(255 * b))
    return colours


def write_room_map(labels: NDArray[np.integer], grid: OccupancyGrid, stem: Path) -> RoomMapFiles:
    """Write a room map's PGM, YAML and colour PNG next to ``stem`` (formats above).

    Raises:
        FloorplanError: more than 254 rooms, or a label array not of the grid's shape.
    """
    from PIL import Image

    if np.shape(labels) != grid.shape:
        msg = f"labels of shape {np.shape(labels)} for a map of shape {grid.shape}"
        raise FloorplanError(msg)
    rooms = compact_labels(np.where(grid.free, labels, 0))
    count = int(rooms.max())
    if count > MAX_LABELS:
        msg = f"{count} rooms: a PGM room map holds at most {MAX_LABELS}"
        raise FloorplanError(msg)
    files = RoomMapFiles(
        stem.with_name(stem.name + ".pgm"),
        stem.with_name(stem.name + ".yaml"),
        stem.with_name(stem.name + ".png"),
        stem.with_name(stem.name + ".rooms.png"),
    )
    grey = np.where(grid.free, rooms, OCCUPIED_GREY).astype(np.uint8)
    # Each file is written beside its name and renamed over it: a reader of a map that is
    # redrawn (``lessmap rooms --fleet``) sees the old file or the new, never half of one.
    with _replacing(files.pgm) as part:
        Image.fromarray(grey, mode="L").save(part, format="PPM")
    ox, oy = grid.origin_xy
    with _replacing(files.yaml) as part:
        part.write_text(
            f"image: {files.pgm.name}\n"
            f"resolution: {grid.resolution_m!r}\n"
            f"origin: [{ox!r}, {oy!r}, 0.0]\n"
            "negate: 1\n"
            "occupied_thresh: 0.999\n"
            "free_thresh: 0.998\n"
            "mode: trinary\n"
            f"rooms: {count}  # grey 1..{count} = room, 0 = free without a room, 255 = occupied\n",
            encoding="utf-8",
        )
    rgb = np.zeros((*grid.shape, 3), dtype=np.uint8)
    rgb[grid.free] = UNLABELLED_RGB
    colours = room_colours(count)
    labelled = rooms > 0
    rgb[labelled] = colours[rooms[labelled]]
    furnished = _furniture_rooms(labels, rooms, grid.free)
    shaded = furnished > 0
    rgb[shaded] = (colours[furnished[shaded]] * FURNITURE_SHADE).astype(np.uint8)
    with _replacing(files.png) as part:
        Image.fromarray(rgb, mode="RGB").save(part, format="PNG")
    every = np.where(grid.free, rooms, furnished).astype(np.uint16)
    with _replacing(files.rooms) as part:
        Image.fromarray(every).save(part, format="PNG")
    return files


def _furniture_rooms(
    labels: NDArray[np.integer], rooms: NDArray[np.int32], free: NDArray[np.bool_]
) -> NDArray[np.int32]:
    """The occupied cells' rooms, numbered as ``rooms`` numbers the free cells' (else 0)."""
    out = np.zeros(rooms.shape, dtype=np.int32)
    given = ~free & (np.asarray(labels) > 0)
    named = free & (rooms > 0)
    if not (given.any() and named.any()):
        return out
    # every label is one room: its free cells all carry one compact number
    original, first = np.unique(np.asarray(labels)[named], return_index=True)
    number = rooms[named][first]
    index = np.clip(np.searchsorted(original, labels[given]), 0, original.size - 1)
    found = original[index] == labels[given]
    out[given] = np.where(found, number[index], 0)
    return out


@contextmanager
def _replacing(path: Path) -> Iterator[Path]:
    """A temporary name beside ``path``, renamed over it when the block succeeds."""
    part = path.with_name(f".{path.name}.part")
    try:
        yield part
        os.replace(part, path)
    finally:
        part.unlink(missing_ok=True)


def read_room_cells(path: Path) -> NDArray[np.int32]:
    """Every cell's room from the ``.rooms.png`` ``write_room_map`` wrote (0 = none).

    Raises:
        FloorplanError: the file is missing or not a 16-bit grey image.
    """
    return read_image(path, ("I;16", "I"), "a 16-bit grey room map")


def read_room_labels(pgm: Path) -> NDArray[np.int32]:
    """The room labels of a PGM ``write_room_map`` wrote (0 = none, walls included).

    Raises:
        FloorplanError: the file is missing or not an 8-bit grey image.
    """
    grey = read_image(pgm, ("L",), "an 8-bit grey room map")
    return np.where(grey == OCCUPIED_GREY, 0, grey).astype(np.int32)

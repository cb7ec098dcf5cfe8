"""Occupancy grids and ground-truth rooms, read from the files room-segmentation tools use.

A map is an image (PNG, PGM, ...) with a resolution in metres per pixel, or a ROS
map_server YAML that names its image, resolution, origin and thresholds. Row 0 of an image
is the top of the map: world y grows upwards, so cell (row, col) has its centre at
``origin + ((col + 0.5) * res, (rows - row - 0.5) * res)``, as map_server places it.

Ground truth follows the room-segmentation benchmark (Bormann et al., ICRA 2016): the free
map with a black line drawn across every doorway; a room is an 8-connected region of grey
above 250, and regions under ``min_room_m2`` are noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

__all__ = [
    "BENCHMARK_RESOLUTION_M",
    "FloorplanError",
    "OccupancyGrid",
    "load_grid",
    "read_image",
    "room_labels",
]

#: Metres per pixel of the benchmark's maps (its own clients' ``map_resolution``).
BENCHMARK_RESOLUTION_M = 0.05
#: The benchmark's free threshold: grey at or above it is free, everything else occupied.
FREE_GREY = 250
#: Its room threshold on the ground-truth image: grey strictly above it is inside a room.
ROOM_GREY = 250


class FloorplanError(ValueError):
    """A map, label image or YAML file that cannot be used; the message names it."""


@dataclass(frozen=True, slots=True, kw_only=True)
class OccupancyGrid:
    """A 2D map: which cells a robot may stand in, and where they are in metres."""

    free: NDArray[np.bool_]  # (rows, cols), row 0 at the top of the image
    resolution_m: float  # side of one cell
    origin_xy: tuple[float, float] = (0.0, 0.0)  # world position of the bottom-left corner

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return (int(self.free.shape[0]), int(self.free.shape[1]))

    def cell_to_xy(
        self, rows: NDArray[np.float64], cols: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Centres of cells (fractional cells allowed) in metres, shape (n, 2)."""
        res = self.resolution_m
        x = self.origin_xy[0] + (np.asarray(cols, dtype=np.float64) + 0.5) * res
        y = self.origin_xy[1] + (self.shape[0] - np.asarray(rows, dtype=np.float64) - 0.5) * res
        return np.stack([x, y], axis=-1)

    def xy_to_cell(self, xy: NDArray[np.float64]) -> NDArray[np.int64]:
        """The cells (row, col) holding points in metres, shape (n, 2); may be outside."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        res = self.resolution_m
        # Clipped one cell beyond the grid first: a pose kilometres off (or 1e300) is still
        # "outside", not an integer overflow.
        rows, cols = self.shape
        col = np.clip(np.floor((xy[:, 0] - self.origin_xy[0]) / res), -1, cols).astype(np.int64)
        up = np.clip(np.floor((xy[:, 1] - self.origin_xy[1]) / res), -1, rows)
        return np.stack([rows - 1 - up.astype(np.int64), col], axis=-1)


def read_image(path: Path, modes: tuple[str, ...] = (), kind: str = "") -> NDArray[np.int32]:
    """An image's pixels: as 8-bit grey (alpha ignored), or as stored when ``modes`` names it.

    Raises:
        FloorplanError: the file is missing, not an image, or (``modes`` given) stored in
            another mode than those (``kind`` says what was expected).
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            if not modes:
                return np.asarray(image.convert("L"), dtype=np.int32)
            if image.mode not in modes:
                msg = f"{path}: not {kind} (mode {image.mode})"
                raise FloorplanError(msg)
            return np.asarray(image, dtype=np.int32)
    except FileNotFoundError:
        msg = f"{path}: no such file"
        raise FloorplanError(msg) from None
    except (UnidentifiedImageError, OSError) as exc:
        msg = f"{path}: not an image this tool reads ({exc.__class__.__name__})"
        raise FloorplanError(msg) from None


def _grey(path: Path) -> NDArray[np.uint8]:
    """An image as 8-bit grey (alpha ignored), as the benchmark reads it."""
    return read_image(path).astype(np.uint8)


def _read_yaml(path: Path) -> dict[str, object]:
    """The flat ``key: value`` subset of YAML that map_server files use."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        msg = f"{path}: no such file"
        raise FloorplanError(msg) from None
    except (UnicodeDecodeError, OSError) as exc:
        msg = f"{path}: cannot read ({exc.__class__.__name__})"
        raise FloorplanError(msg) from None
    values: dict[str, object] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        key, sep, value = line.partition(":")
        if not sep:
            msg = f"{path}:{number}: expected 'key: value'"
            raise FloorplanError(msg)
        value = value.strip().strip("'\"")
        if value.startswith("["):
            try:
                values[key.strip()] = [float(v) for v in value.strip("[]").split(",")]
            except ValueError:
                msg = f"{path}:{number}: {key.strip()} is not a list of numbers"
                raise FloorplanError(msg) from None
        else:
            values[key.strip()] = value
    return values


def load_grid(path: Path, resolution_m: float | None = None) -> OccupancyGrid:
    """Read a map image (with ``resolution_m``, default the benchmark's) or a map_server YAML.

    Raises:
        FloorplanError: the file is missing, unreadable, or its YAML lacks what a map needs.
    """
    if path.suffix.lower() in {".yaml", ".yml"}:
        meta = _read_yaml(path)
        try:
            image = path.parent / str(meta["image"])
            res = float(str(meta["resolution"]))
            origin = meta.get("origin", [0.0, 0.0, 0.0])
            negate = int(str(meta.get("negate", "0")))
            free_thresh = float(str(meta.get("free_thresh", "0.196")))
        except (KeyError, ValueError) as exc:
            msg = f"{path}: map YAML needs image and resolution ({exc})"
            raise FloorplanError(msg) from None
        grey = _grey(image).astype(np.float64)
        # map_server: occupancy = (255 - grey) / 255 (or grey / 255 when negated)
        occ = grey / 255.0 if negate else (255.0 - grey) / 255.0
        free = occ < free_thresh
        ox, oy = [*list(origin), 0.0, 0.0][:2] if isinstance(origin, list) else (0.0, 0.0)
        return _checked(OccupancyGrid(free=free, resolution_m=res, origin_xy=(ox, oy)), path)
    res = BENCHMARK_RESOLUTION_M if resolution_m is None else resolution_m
    if not res > 0:
        msg = f"resolution must be above 0 m a pixel, got {res}"
        raise FloorplanError(msg)
    return _checked(OccupancyGrid(free=_grey(path) >= FREE_GREY, resolution_m=res), path)


def _checked(grid: OccupancyGrid, path: Path) -> OccupancyGrid:
    if not grid.resolution_m > 0:
        msg = f"{path}: resolution must be above 0, got {grid.resolution_m}"
        raise FloorplanError(msg)
    if not grid.free.any():
        msg = f"{path}: no free cell (free is grey >= {FREE_GREY})"
        raise FloorplanError(msg)
    return grid


def room_labels(
    path: Path, resolution_m: float = BENCHMARK_RESOLUTION_M, min_room_m2: float = 1.0
) -> NDArray[np.int32]:
    """Rooms of a ground-truth image: (rows, cols), 0 outside any room, rooms 1..k.

    Rooms are 8-connected regions of grey above 250 of at least ``min_room_m2``, numbered
    in raster order of their first cell.

    Raises:
        FloorplanError: the image is missing or unreadable, or holds no room.
    """
    inside = _grey(path) > ROOM_GREY
    labels, count = ndimage.label(inside, structure=np.ones((3, 3), dtype=bool))
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    keep = sizes >= min_room_m2 / resolution_m**2
    keep[0] = False
    renumber = np.zeros(count + 1, dtype=np.int32)
    renumber[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    rooms = renumber[labels]
    if not keep.any():
        msg = f"{path}: no room (a room is a region of grey above {ROOM_GREY} of {min_room_m2} m2)"
        raise FloorplanError(msg)
    return rooms

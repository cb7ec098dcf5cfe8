"""Benchmark cases and the simulators that produce them: what ``lessmap.floorplan.bench`` runs.

A simulator is any callable ``(case, folder) -> SimulatedRun``, picklable (a module-level
function) so that cases run in worker processes: it writes ``<name>.frames.jsonl`` (with
poses) and ``<name>.truth.jsonl`` (``TruthRow`` lines) into ``folder`` and names the
occupancy map and the ground-truth room image the run is scored on.

``FloorplanSimulator`` tours a benchmark floor plan (``lessmap.floorplan.simulation``):
``case.map`` names the map, ``case.sensor`` a sensor profile. ``building_run`` is the
generated-building simulator of ``lessmap.sim`` seen as a floor
plan: ``case.map`` is its layout (``grid`` or ``corridor``), and its building is drawn into
an occupancy image with its map_server YAML (walls black, two cells thick; doors open) and a
ground-truth image (the same with every doorway closed), at ``RESOLUTION_M``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from lessmap.sim.building import Building

__all__ = [
    "SENSORS",
    "BenchCase",
    "FloorplanSimulator",
    "SimulatedRun",
    "Simulator",
    "benchmark_map",
    "building_run",
    "draw_building",
]

RESOLUTION_M = 0.05
MARGIN_M = 0.5
WALL_HALF_M = 0.05  # walls two cells thick, drawn on both sides of their line
DURATION_S = 300.0  # each robot's walk
ROBOTS = 2
ROOMS = 8

#: Sensors by name: the simulator's options for each.
SENSORS: dict[str, dict[str, Any]] = {
    "laser270": {"fov_deg": 270.0, "range_m": 5.0},
    "laser360": {"fov_deg": 360.0, "range_m": 5.0},
    "camera90": {"fov_deg": 90.0, "range_m": 4.0},
}


@dataclass(frozen=True, slots=True, kw_only=True)
class BenchCase:
    """One simulated run of the benchmark."""

    map: str  # a floor plan's name (or a generated building's layout)
    sensor: str  # a key of SENSORS
    seed: int
    rate_hz: float

    @property
    def name(self) -> str:
        """A file-name stem for the run."""
        return f"{self.map}-{self.sensor}-s{self.seed}-{self.rate_hz:g}hz"


@dataclass(frozen=True, slots=True, kw_only=True)
class SimulatedRun:
    """The files of one run."""

    frames: Path  # <name>.frames.jsonl, with poses
    truth: Path  # <name>.truth.jsonl
    grid_map: Path  # occupancy image or map_server YAML, in the poses' frame
    labels: Path  # ground-truth room image of the same size
    resolution_m: float | None = None  # of an image map (None: the benchmark's 0.05)


class Simulator(Protocol):
    """Runs a case and writes its files into a folder."""

    def __call__(self, case: BenchCase, folder: Path) -> SimulatedRun: ...  # noqa: D102


def benchmark_map(name: str, folder: Path, *, furnished: bool = False) -> tuple[Path, Path]:
    """The occupancy image and ground-truth rooms of a room-segmentation benchmark map.

    ``folder`` holds the benchmark's files (``../shared/floorplans``): ``<name>.png`` or
    ``<name>_furnitures.png``, and ``<name>_gt_segmentation.png``; 0.05 m a pixel.

    Raises:
        FloorplanError: either file is missing.
    """
    from lessmap.floorplan.grid import FloorplanError

    image = folder / (f"{name}_furnitures.png" if furnished else f"{name}.png")
    labels = folder / f"{name}_gt_segmentation.png"
    for path in (image, labels):
        if not path.is_file():
            msg = f"{path}: no such file (benchmark map {name!r})"
            raise FloorplanError(msg)
    return image, labels


def draw_building(building: Building) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    """Occupancy and ground-truth grey images (uint8) of a building, origin at (-margin, -margin).

    Free cells inside a room are 255, walls 0, outside 0; the ground truth also closes every
    door with a wall line.
    """
    xs = [v for room in building.rooms for v in (room.rect.x0, room.rect.x1)]
    ys = [v for room in building.rooms for v in (room.rect.y0, room.rect.y1)]
    width_m = max(xs) + 2 * MARGIN_M
    height_m = max(ys) + 2 * MARGIN_M
    cols = int(np.ceil(width_m / RESOLUTION_M))
    rows = int(np.ceil(height_m / RESOLUTION_M))
    x = (np.arange(cols) + 0.5) * RESOLUTION_M - MARGIN_M
    y = (rows - np.arange(rows) - 0.5) * RESOLUTION_M - MARGIN_M
    gx, gy = np.meshgrid(x, y)
    free = np.zeros((rows, cols), dtype=bool)
    for room in building.rooms:
        r = room.rect
        free |= (gx >= r.x0) & (gx <= r.x1) & (gy >= r.y0) & (gy <= r.y1)

    def line(x0: float, y0: float, x1: float, y1: float) -> np.ndarray[Any, Any]:
        lo_x, hi_x = min(x0, x1) - WALL_HALF_M, max(x0, x1) + WALL_HALF_M
        lo_y, hi_y = min(y0, y1) - WALL_HALF_M, max(y0, y1) + WALL_HALF_M
        hit: np.ndarray[Any, Any] = (gx >= lo_x) & (gx <= hi_x) & (gy >= lo_y) & (gy <= hi_y)
        return hit

    walls = np.zeros_like(free)
    for wall in building.walls:
        walls |= line(wall.x0, wall.y0, wall.x1, wall.y1)
    doors = np.zeros_like(free)
    for door in building.doors:
        half = door.width_m / 2
        if door.vertical:
            doors |= line(door.x, door.y - half, door.x, door.y + half)
        else:
            doors |= line(door.x - half, door.y, door.x + half, door.y)
    occupancy = np.where(free & ~walls, 255, 0).astype(np.uint8)
    truth = np.where(free & ~walls & ~doors, 255, 0).astype(np.uint8)
    return occupancy, truth


def building_run(case: BenchCase, folder: Path) -> SimulatedRun:
    """Simulate ``case`` in a generated building (``lessmap.sim``) and draw its floor plan."""
    from PIL import Image

    from lessmap.floorplan.grid import FloorplanError
    from lessmap.sim.simulator import simulate, write_run

    if case.sensor not in SENSORS:
        msg = f"unknown sensor {case.sensor!r}; known: {', '.join(SENSORS)}"
        raise FloorplanError(msg)
    try:
        run = simulate(
            case.seed,
            rooms=ROOMS,
            robots=ROBOTS,
            frames_per_robot=round(DURATION_S * case.rate_hz),
            layout=case.map,
            rate_hz=case.rate_hz,
            **SENSORS[case.sensor],
        )
    except ValueError as exc:
        msg = f"case {case.name}: {exc}"
        raise FloorplanError(msg) from None
    paths = write_run(run, folder, case.name)
    occupancy, truth = draw_building(run.building)
    image = folder / f"{case.name}.map.png"
    labels = folder / f"{case.name}.gt.png"
    Image.fromarray(occupancy, mode="L").save(image)
    Image.fromarray(truth, mode="L").save(labels)
    grid_map = folder / f"{case.name}.map.yaml"
    grid_map.write_text(
        f"image: {image.name}\nresolution: {RESOLUTION_M}\n"
        f"origin: [{-MARGIN_M}, {-MARGIN_M}, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        encoding="utf-8",
    )
    return SimulatedRun(frames=paths.frames, truth=paths.truth, grid_map=grid_map, labels=labels)


#: Walking speed of the floor-plan robots, whatever the frame rate.
FLOORPLAN_SPEED_MPS = 1.0


@dataclass(frozen=True, slots=True)
class FloorplanSimulator:
    """Tour a benchmark map of ``folder`` (``benchmark_map``) with the floor-plan simulator.

    Every room is toured by ``robots`` robots at ``FLOORPLAN_SPEED_MPS`` times
    ``speed_factor``; the sensor is ``case.sensor``, a profile of
    ``lessmap.floorplan.options.PROFILES``, with ``sensor_changes`` (``SensorProfile`` fields)
    and the walk's ``tour_changes`` (``TourOptions`` fields) applied: other simulators than
    the default are the same one with some settings changed.
    """

    folder: Path
    furnished: bool = False
    robots: int = ROBOTS
    sensor_changes: Mapping[str, Any] = field(default_factory=dict)
    tour_changes: Mapping[str, Any] = field(default_factory=dict)
    speed_factor: float = 1.0

    def __post_init__(self) -> None:
        # A misspelt setting of a user's own variant is a one-line error, not a worker's
        # traceback halfway through a benchmark.
        from dataclasses import fields

        from lessmap.floorplan.grid import FloorplanError
        from lessmap.floorplan.options import SensorProfile, TourOptions

        for changes, kind in (
            (self.sensor_changes, SensorProfile),
            (self.tour_changes, TourOptions),
        ):
            unknown = sorted(set(changes) - {f.name for f in fields(kind)})
            if unknown:
                msg = f"no {kind.__name__} field {', '.join(unknown)}"
                raise FloorplanError(msg)
        if not self.speed_factor > 0.0:
            msg = f"speed_factor must be > 0, got {self.speed_factor}"
            raise FloorplanError(msg)

    def __call__(self, case: BenchCase, folder: Path) -> SimulatedRun:
        """Simulate ``case`` and write its files into ``folder``."""
        from lessmap.floorplan.grid import FloorplanError, load_grid, room_labels
        from lessmap.floorplan.options import PROFILES, FloorplanOptions, TourOptions
        from lessmap.floorplan.runfiles import write_floorplan_run
        from lessmap.floorplan.simulation import simulate_floorplan

        if case.sensor not in PROFILES:
            msg = f"unknown sensor {case.sensor!r}; floor plans know {', '.join(PROFILES)}"
            raise FloorplanError(msg)
        image, labels = benchmark_map(case.map, self.folder, furnished=self.furnished)
        grid = load_grid(image)
        speed_m_per_frame = FLOORPLAN_SPEED_MPS * self.speed_factor / case.rate_hz
        tour = TourOptions(rate_hz=case.rate_hz, speed_m_per_frame=speed_m_per_frame)
        options = FloorplanOptions(
            sensor=replace(PROFILES[case.sensor], **self.sensor_changes),
            robots=self.robots,
            seed=case.seed,
            tour=replace(tour, **self.tour_changes),
        )
        run = simulate_floorplan(grid, room_labels(labels, grid.resolution_m), options)
        sources = {"map": str(image), "labels": str(labels)}
        paths = write_floorplan_run(run, grid, folder, case.name, sources)
        return SimulatedRun(frames=paths.frames, truth=paths.truth, grid_map=image, labels=labels)

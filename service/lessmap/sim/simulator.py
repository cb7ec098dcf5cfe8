"""A simulated fleet in a seeded building: frames for lessmap, with the ground truth to score it.

Robots walk routes through a generated floor plan (``building.py``): from room to room via
the doors, lingering at a few points in each room, going back and forth so areas are
revisited. A laser-like sensor reports the wall landmarks in range and in line of sight (walls
block it; door openings don't), each detected with ``detection_prob``. Everything is pure
Python and drawn from ``random.Random`` seeded by ``seed``: the same call gives the same run.
Each robot has its own route and sensor streams, so adding robots leaves the others unchanged.

Files written by ``write_run(run, out_dir, name)``:

``<name>.frames.jsonl``
    The neutral frames format (shared datasets README): one line per frame, robots
    interleaved by stamp, ``{"robot", "seq", "stamp", "features", "pose": [x, y, theta]}``.
    Stamps are seconds; the pose is the true pose (metres, radians).
``<name>.truth.jsonl``
    One line per frame, same order: ``{"robot", "seq", "stamp", "room", "x", "y",
    "door_near": {"door": <id>, "distance_m": <m>}}`` (``door_near`` is null in a building
    without doors). ``room`` is the index of the room holding the robot's position (a point
    on a shared wall line counts for the lower index); x, y in metres. A line is a
    ``TruthRow``.
``<name>.building.json``
    ``{"seed", "options", "rooms": [{"index", "rect": {"x0", "y0", "x1", "y1"}, "kind"}],
    "walls": [{"x0", "y0", "x1", "y1", "sides": [room | null, room | null]}], "doors": [{"id",
    "x", "y", "rooms": [a, b], "width_m", "vertical"}], "landmarks": [{"id", "x", "y", "room",
    "nx", "ny"}], "room_changes": [{"robot", "seq", "from_room", "to_room", "door"}]}``.
    Metres; walls have the door openings cut out; a landmark faces its room along (nx, ny);
    a room change's ``seq`` is the first frame in the new room. ``Building.from_json`` reads
    the plan back.

``read_truth(frames_path)`` reads the truth and building files back (``SimTruth``): the one
reader of these formats, used by the evaluation. A building file without ``room_changes``
gives the changes of the truth rows, each at the door its change frame's ``door_near`` names.
"""

from __future__ import annotations

import json
import math
import random
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from lessmap.sim.building import Building, Door, Rect, generate_building
from lessmap.sim.groundtruth import changes_from_truth

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

__all__ = [
    "RoomChange",
    "RunPaths",
    "SimOptions",
    "SimRun",
    "SimTruth",
    "TruthRow",
    "iter_frames",
    "read_truth",
    "run_paths",
    "simulate",
    "write_run",
]

APPROACH_M = 0.6  # robots line up this far in front of a door before passing it
WALL_CLEARANCE_M = 0.8  # random waypoints keep this far from the walls


@dataclass(frozen=True, slots=True, kw_only=True)
class SimOptions:
    """World, sensor and motion settings (defaults: offices seen by a 270° laser scanner)."""

    layout: str = "grid"  # "grid": two rows of rooms; "corridor": rooms along a corridor
    room_size_m: tuple[float, float] = (4.0, 8.0)  # width and depth drawn per column/row
    corridor_width_m: tuple[float, float] = (1.8, 2.6)
    door_width_m: float = 1.0
    extra_door_prob: float = 0.25  # doors beyond the spanning tree: loops in the door graph
    landmark_spacing_m: tuple[float, float] = (0.6, 1.2)  # along each wall, drawn per gap
    range_m: float = 5.0
    detection_prob: float = 0.8  # per visible landmark and frame
    # 270°: a SICK LMS1xx / Hokuyo UTM-30LX class indoor scanner, the common case. It loses
    # the old room once through a door; a 360° lidar keeps seeing it through the door behind,
    # which delays transitions about 2x (measured in tests/sim/test_sim.py). ~60-90: camera.
    fov_deg: float = 270.0
    speed_mps: float = 0.5
    rate_hz: float = 2.0
    wander_points: tuple[int, int] = (0, 2)  # extra random waypoints per room visit
    dwell_s: tuple[float, float] = (0.0, 3.0)  # pause at each waypoint inside a room
    back_prob: float = 0.2  # chance of turning back through the door just used


@dataclass(frozen=True, slots=True)
class TruthRow:
    """Where a robot really was at one frame (a line of ``<name>.truth.jsonl``).

    The heading is in the frame's ``pose``, not here.
    """

    robot: str
    seq: int
    stamp: float
    room: int
    x: float
    y: float
    door: int | None  # nearest door (None in a building without doors)
    door_distance_m: float  # inf without doors


@dataclass(frozen=True, slots=True)
class RoomChange:
    """A robot entered another room: ``seq`` is its first frame there."""

    robot: str
    seq: int
    from_room: int
    to_room: int
    door: int


@dataclass(slots=True)
class SimRun:
    """One simulated run: the building, the frames and their ground truth."""

    seed: int
    options: SimOptions
    building: Building
    frames: list[dict[str, Any]] = field(default_factory=list)  # the frames-file rows
    truth: list[TruthRow] = field(default_factory=list)  # same order as frames
    room_changes: list[RoomChange] = field(default_factory=list)

    @property
    def doors(self) -> dict[int, Door]:
        """Doors by id (position and the two rooms each joins)."""
        return {door.id: door for door in self.building.doors}

    def changes_of(self, robot: str) -> list[RoomChange]:
        """The true room changes of one robot, in order."""
        return [change for change in self.room_changes if change.robot == robot]


class RunPaths(NamedTuple):
    """The files of a run: what ``write_run`` wrote, or ``run_paths`` names."""

    frames: Path
    truth: Path
    building: Path


@dataclass(frozen=True, slots=True)
class SimTruth:
    """The ground truth of a run as its files hold it (``read_truth``)."""

    rows: tuple[TruthRow, ...]  # file order: robots interleaved by stamp
    doors: tuple[Door, ...]
    changes: tuple[RoomChange, ...]
    landmarks: dict[int, tuple[float, float]] = field(default_factory=dict)  # id → x, y
    walls: tuple[tuple[float, float, float, float], ...] = ()  # x0, y0, x1, y1 (for figures)

    def positions(self) -> dict[tuple[str, int], tuple[float, float]]:
        """Map (robot, seq) to the true position (x, y)."""
        return {(row.robot, row.seq): (row.x, row.y) for row in self.rows}


def simulate(
    seed: int = 0, rooms: int = 6, robots: int = 3, frames_per_robot: int = 400, **options: Any
) -> SimRun:
    """Simulate ``robots`` robots walking a building of ``rooms`` rooms.

    Args:
        seed: Seeds the building, every route and every sensor.
        rooms: Offices in the building (the ``corridor`` layout adds the corridor).
        robots: Robots, named ``robot0``, ``robot1``, ...
        frames_per_robot: Frames each robot records, at ``rate_hz``.
        **options: Any ``SimOptions`` field.

    Returns:
        The run; its frames are sorted by stamp (robots start a fraction of a period apart).
    """
    known = {f.name for f in fields(SimOptions)}
    unknown = sorted(set(options) - known)
    if unknown:
        msg = (
            f"unknown simulation option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
        )
        raise TypeError(msg)
    opts = SimOptions(**options)
    if robots < 1 or frames_per_robot < 0 or opts.rate_hz <= 0 or opts.speed_mps <= 0:
        msg = (
            f"need robots >= 1, frames >= 0, rate and speed > 0 (got {robots}, {frames_per_robot})"
        )
        raise ValueError(msg)
    building = generate_building(
        random.Random(f"lessmap-sim/{seed}/building"),
        rooms,
        layout=opts.layout,
        room_size_m=opts.room_size_m,
        corridor_width_m=opts.corridor_width_m,
        door_width_m=opts.door_width_m,
        extra_door_prob=opts.extra_door_prob,
        landmark_spacing_m=opts.landmark_spacing_m,
    )
    run = SimRun(seed=seed, options=opts, building=building)
    period = 1.0 / opts.rate_hz
    rows: list[tuple[float, int, dict[str, Any], TruthRow]] = []
    for index in range(robots):
        robot = f"robot{index}"
        offset = index * period / robots
        route_rng = random.Random(f"lessmap-sim/{seed}/route/{index}")
        sensor_rng = random.Random(f"lessmap-sim/{seed}/sensor/{index}")
        poses = _poses(building, route_rng, opts)
        previous: int | None = None
        for seq in range(frames_per_robot):
            x, y, theta = next(poses)
            stamp = round(offset + seq * period, 6)
            visible = building.visible(x, y, theta, opts.range_m, opts.fov_deg)
            features = sorted(i for i in visible if sensor_rng.random() < opts.detection_prob)
            room = building.room_at(x, y)
            assert room is not None, "routes stay inside the building"
            door, distance = building.nearest_door(x, y)
            pose = [round(x, 4), round(y, 4), round(theta, 4)]
            frame = {"robot": robot, "seq": seq, "stamp": stamp, "features": features, "pose": pose}
            truth = TruthRow(robot, seq, stamp, room, pose[0], pose[1], door, round(distance, 4))
            rows.append((stamp, index, frame, truth))
            if previous is not None and room != previous:
                run.room_changes.append(
                    RoomChange(
                        robot, seq, previous, room, _door_between(building, previous, room, x, y)
                    )
                )
            previous = room
    rows.sort(key=lambda row: (row[0], row[1]))
    run.frames = [row[2] for row in rows]
    run.truth = [row[3] for row in rows]
    return run


def _door_between(building: Building, a: int, b: int, x: float, y: float) -> int:
    doors = [d for d in building.doors if set(d.rooms) == {a, b}]
    return min(doors, key=lambda d: math.hypot(d.x - x, d.y - y)).id


# -- motion ------------------------------------------------------------------------------------


def _legs(
    building: Building, rng: random.Random, opts: SimOptions, room: int
) -> Iterator[tuple[float, float, float]]:
    """Yield the route as (x, y, pause_s) waypoints: walk to (x, y), then wait pause_s."""
    came_through: int | None = None
    while True:
        rect = building.rooms[room].rect
        if building.rooms[room].kind == "room":
            cx, cy = rect.centre
            yield (
                cx + rng.uniform(-0.4, 0.4),
                cy + rng.uniform(-0.4, 0.4),
                rng.uniform(*opts.dwell_s),
            )
        for _ in range(rng.randint(*opts.wander_points)):
            yield (*_interior_point(rng, rect), rng.uniform(*opts.dwell_s))
        exits = building.neighbours(room)
        if not exits:
            yield (*_interior_point(rng, rect), rng.uniform(*opts.dwell_s))
            continue
        onward = [e for e in exits if e[0].id != came_through]
        door, following = rng.choice(onward if onward and rng.random() >= opts.back_prob else exits)
        yield (*door.side_point(room, APPROACH_M), 0.0)
        yield (door.x, door.y, 0.0)
        yield (*door.side_point(following, APPROACH_M), 0.0)
        room, came_through = following, door.id


def _interior_point(rng: random.Random, rect: Rect) -> tuple[float, float]:
    margin_x = min(WALL_CLEARANCE_M, (rect.x1 - rect.x0) / 2)
    margin_y = min(WALL_CLEARANCE_M, (rect.y1 - rect.y0) / 2)
    return (
        rng.uniform(rect.x0 + margin_x, rect.x1 - margin_x),
        rng.uniform(rect.y0 + margin_y, rect.y1 - margin_y),
    )


def _poses(
    building: Building, rng: random.Random, opts: SimOptions
) -> Iterator[tuple[float, float, float]]:
    """Yield the pose at every frame period along an endless route."""
    room = rng.randrange(len(building.rooms))
    x, y = _interior_point(rng, building.rooms[room].rect)
    theta = rng.uniform(-math.pi, math.pi)
    period = 1.0 / opts.rate_hz
    until_frame = 0.0  # seconds of route left before the next frame is taken
    for tx, ty, pause_s in _legs(building, rng, opts, room):
        length = math.hypot(tx - x, ty - y)
        if length > 1e-9:
            theta = math.atan2(ty - y, tx - x)
            walk_s = length / opts.speed_mps
            while until_frame <= walk_s:
                walk_s -= until_frame
                share = 1.0 - walk_s * opts.speed_mps / length
                yield (x + share * (tx - x), y + share * (ty - y), theta)
                until_frame = period
            until_frame -= walk_s
        x, y = tx, ty
        while until_frame <= pause_s:
            pause_s -= until_frame
            yield (x, y, theta)
            until_frame = period
        until_frame -= pause_s
    msg = "routes never end"
    raise AssertionError(msg)  # pragma: no cover


# -- output ------------------------------------------------------------------------------------


def write_run(run: SimRun, out_dir: str | Path, name: str) -> RunPaths:
    """Write the frames, truth and building files of a run (formats: module docstring)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = RunPaths(
        out / f"{name}.frames.jsonl", out / f"{name}.truth.jsonl", out / f"{name}.building.json"
    )
    with paths.frames.open("w", encoding="utf-8") as stream:
        for frame in run.frames:
            stream.write(json.dumps(frame, separators=(",", ":")) + "\n")
    with paths.truth.open("w", encoding="utf-8") as stream:
        for row in run.truth:
            line = {
                "robot": row.robot,
                "seq": row.seq,
                "stamp": row.stamp,
                "room": row.room,
                "x": row.x,
                "y": row.y,
                "door_near": None
                if row.door is None
                else {"door": row.door, "distance_m": row.door_distance_m},
            }
            stream.write(json.dumps(line, separators=(",", ":")) + "\n")
    document = {"seed": run.seed, "options": asdict(run.options), **run.building.to_json()}
    document["room_changes"] = [asdict(change) for change in run.room_changes]
    paths.building.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    return paths


FRAMES_SUFFIX = ".frames.jsonl"


def run_paths(frames_path: str | Path) -> RunPaths:
    """Name the truth and building files next to ``<name>.frames.jsonl``.

    Raises:
        ValueError: the name does not end in ``.frames.jsonl``.
    """
    frames = Path(frames_path)
    if not frames.name.endswith(FRAMES_SUFFIX):
        msg = f"{frames}: a frames file name must end in {FRAMES_SUFFIX}"
        raise ValueError(msg)
    stem = frames.name[: -len(FRAMES_SUFFIX)]
    return RunPaths(
        frames, frames.with_name(f"{stem}.truth.jsonl"), frames.with_name(f"{stem}.building.json")
    )


def read_truth(frames_path: str | Path) -> SimTruth:
    """Read the truth and building files of a run back (formats: module docstring).

    Raises:
        OSError: a file cannot be read (``FileNotFoundError`` when missing).
        ValueError: a file is malformed; the message names the file (and line).
    """
    paths = run_paths(frames_path)
    with paths.truth.open(encoding="utf-8") as handle:
        rows = tuple(
            _truth_row(line, f"{paths.truth.name}:{number}")
            for number, line in enumerate(handle, start=1)
            if line.strip()
        )
    try:
        document = json.loads(paths.building.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        msg = f"{paths.building.name}: not JSON ({exc.msg})"
        raise ValueError(msg) from exc
    try:
        building = Building.from_json(document)
        listed = document.get("room_changes")
        changes = (
            _changes_from_rows(rows)
            if listed is None
            else tuple(
                RoomChange(
                    str(c["robot"]),
                    int(c["seq"]),
                    int(c["from_room"]),
                    int(c["to_room"]),
                    int(c["door"]),
                )
                for c in listed
            )
        )
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
        msg = f"{paths.building.name}: unexpected layout ({exc!r})"
        raise ValueError(msg) from exc
    return SimTruth(
        rows=rows,
        doors=building.doors,
        changes=changes,
        landmarks={mark.id: (mark.x, mark.y) for mark in building.landmarks},
        walls=tuple((w.x0, w.y0, w.x1, w.y1) for w in building.walls),
    )


def _truth_row(line: str, where: str) -> TruthRow:
    try:
        row = json.loads(line)
        near = row["door_near"]
        return TruthRow(
            robot=str(row["robot"]),
            seq=int(row["seq"]),
            stamp=float(row["stamp"]),
            room=int(row["room"]),
            x=float(row["x"]),
            y=float(row["y"]),
            door=None if near is None else int(near["door"]),
            door_distance_m=math.inf if near is None else float(near["distance_m"]),
        )
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        msg = f"{where}: not a truth row ({exc!r})"
        raise ValueError(msg) from exc


def _changes_from_rows(rows: tuple[TruthRow, ...]) -> tuple[RoomChange, ...]:
    """The room changes of the truth rows, each at the door its change frame is nearest."""
    door_of = {(row.robot, row.seq): row.door for row in rows}
    changes = []
    for change in changes_from_truth(rows):
        door = door_of[(change["robot"], change["seq"])]
        if door is None:
            msg = f"robot {change['robot']!r} changes room at seq {change['seq']} without a door"
            raise ValueError(msg)
        changes.append(
            RoomChange(change["robot"], change["seq"], change["from_room"], change["to_room"], door)
        )
    return tuple(changes)


def iter_frames(
    run: SimRun,
    *,
    speed: float | None = None,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> Iterator[dict[str, Any]]:
    """Yield the frames in stamp order, paced like the robots recorded them.

    Args:
        run: The simulated run.
        speed: Playback rate: 1.0 is real time, 10.0 ten times faster; None yields at once.
        sleep: Waits that many seconds (inject a fake to test pacing without waiting).
        clock: Monotonic seconds.
    """
    if speed is not None and speed <= 0:
        msg = f"speed must be positive or None, got {speed}"
        raise ValueError(msg)
    start = clock()
    first = run.frames[0]["stamp"] if run.frames else 0.0
    for frame in run.frames:
        if speed is not None:
            wait = start + (frame["stamp"] - first) / speed - clock()
            if wait > 0:
                sleep(wait)
        yield frame

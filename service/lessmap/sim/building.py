"""A seeded floor plan for the simulator: rectangular rooms, walls, doors and wall landmarks.

Invariants of this file:

1. Rooms are axis-aligned rectangles cut from one grid of columns and rows, so every wall is
   an axis-aligned segment on a grid line. That keeps the line-of-sight test exact and cheap.
2. A wall has two sides (room index or ``None`` for outside). A door is a gap of
   ``door_width_m`` in the wall two rooms share; walls are stored with the gaps cut out.
3. Landmarks sit on a wall and face one room (their ``room``). Line of sight is tested to a
   point ``FACE_OFFSET_M`` in front of the landmark, so the wall it sits on never hides it
   from its own room and always hides it from the other side.
4. Everything random comes from the one ``random.Random`` passed in: same seed, same building.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import random
    from collections.abc import Iterator

FACE_OFFSET_M = 0.05  # how far in front of its wall a landmark is tested for visibility
DOOR_MARGIN_M = 0.5  # least wall left between a door and a corner
LAYOUTS = ("grid", "corridor")


@dataclass(frozen=True, slots=True)
class Rect:
    """An axis-aligned rectangle, metres."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def centre(self) -> tuple[float, float]:
        """The centre point."""
        return (0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1))

    def contains(self, x: float, y: float, margin: float = 0.0) -> bool:
        """Whether (x, y) lies inside, at least ``margin`` from every side."""
        return (
            self.x0 + margin <= x <= self.x1 - margin and self.y0 + margin <= y <= self.y1 - margin
        )


@dataclass(frozen=True, slots=True)
class Room:
    """One area of the building: an office or the corridor."""

    index: int
    rect: Rect
    kind: str  # "room" or "corridor"


@dataclass(frozen=True, slots=True)
class Wall:
    """A wall segment (door gaps already cut out) and the rooms on its two sides."""

    x0: float
    y0: float
    x1: float
    y1: float
    sides: tuple[int | None, int | None]  # (left or below, right or above); None = outside

    @property
    def vertical(self) -> bool:
        """Whether the wall runs along y (constant x)."""
        return self.x0 == self.x1


@dataclass(frozen=True, slots=True)
class Door:
    """An opening of ``width_m`` in the wall between two rooms, centred at (x, y)."""

    id: int
    x: float
    y: float
    rooms: tuple[int, int]  # (left or below, right or above)
    width_m: float
    vertical: bool  # the wall it is in runs along y

    def side_point(self, room: int, offset_m: float) -> tuple[float, float]:
        """The point ``offset_m`` in front of the door, on the side of ``room``."""
        sign = -1.0 if room == self.rooms[0] else 1.0
        if self.vertical:
            return (self.x + sign * offset_m, self.y)
        return (self.x, self.y + sign * offset_m)


@dataclass(frozen=True, slots=True)
class Landmark:
    """A point feature on a wall, facing ``room`` along the unit normal (nx, ny)."""

    id: int
    x: float
    y: float
    room: int
    nx: float
    ny: float


@dataclass(frozen=True, slots=True)
class Building:
    """The floor plan: rooms, walls, doors and landmarks. Geometry queries only, no randomness."""

    rooms: tuple[Room, ...]
    walls: tuple[Wall, ...]
    doors: tuple[Door, ...]
    landmarks: tuple[Landmark, ...]

    def room_at(self, x: float, y: float) -> int | None:
        """Index of the room holding (x, y); on a shared wall line, the lower index."""
        for room in self.rooms:
            if room.rect.contains(x, y):
                return room.index
        return None

    def nearest_door(self, x: float, y: float) -> tuple[int | None, float]:
        """Id of the door nearest (x, y) and its distance, metres (None, inf without doors)."""
        if not self.doors:
            return None, math.inf
        best = min(self.doors, key=lambda d: (d.x - x) ** 2 + (d.y - y) ** 2)
        return best.id, math.hypot(best.x - x, best.y - y)

    def neighbours(self, room: int) -> list[tuple[Door, int]]:
        """Doors out of ``room`` and the room each leads to."""
        out = []
        for door in self.doors:
            if room in door.rooms:
                out.append((door, door.rooms[1] if door.rooms[0] == room else door.rooms[0]))
        return out

    def line_of_sight(self, px: float, py: float, qx: float, qy: float) -> bool:
        """Whether the segment P→Q crosses no wall (door openings let it through)."""
        lo_x, hi_x = min(px, qx), max(px, qx)
        lo_y, hi_y = min(py, qy), max(py, qy)
        for wall in self.walls:
            if wall.vertical:
                x = wall.x0
                if not lo_x <= x <= hi_x or wall.y1 < lo_y or wall.y0 > hi_y:
                    continue
                if px == qx:  # runs along the wall line: blocked where it overlaps
                    return False
                y = py + (x - px) / (qx - px) * (qy - py)
                if wall.y0 <= y <= wall.y1:  # door jambs (segment ends) block too
                    return False
            else:
                y = wall.y0
                if not lo_y <= y <= hi_y or wall.x1 < lo_x or wall.x0 > hi_x:
                    continue
                if py == qy:
                    return False
                x = px + (y - py) / (qy - py) * (qx - px)
                if wall.x0 <= x <= wall.x1:
                    return False
        return True

    def visible(
        self, x: float, y: float, theta: float, range_m: float, fov_deg: float = 360.0
    ) -> list[int]:
        """Ids of the landmarks a sensor at (x, y, heading theta) could see, before dropouts.

        A landmark is visible when it lies within ``range_m``, inside the field of view, and
        the segment to the point ``FACE_OFFSET_M`` in front of it crosses no wall.
        """
        half_fov = math.radians(fov_deg) / 2.0
        seen = []
        for mark in self.landmarks:
            dx, dy = mark.x - x, mark.y - y
            if dx * dx + dy * dy > range_m * range_m:
                continue
            if half_fov < math.pi:
                bearing = math.atan2(dy, dx) - theta
                if abs(math.atan2(math.sin(bearing), math.cos(bearing))) > half_fov:
                    continue
            tx, ty = mark.x + FACE_OFFSET_M * mark.nx, mark.y + FACE_OFFSET_M * mark.ny
            if self.line_of_sight(x, y, tx, ty):
                seen.append(mark.id)
        return seen

    def to_json(self) -> dict[str, Any]:
        """Return the plan as JSON-ready values (the dataclass fields, by name)."""
        return {name: [asdict(item) for item in getattr(self, name)] for name in _PARTS}

    @classmethod
    def from_json(cls, document: dict[str, Any]) -> Building:
        """Rebuild a plan from ``to_json`` output (e.g. a ``<name>.building.json``)."""
        return cls(
            rooms=tuple(Room(r["index"], Rect(**r["rect"]), r["kind"]) for r in document["rooms"]),
            walls=tuple(
                Wall(w["x0"], w["y0"], w["x1"], w["y1"], tuple(w["sides"]))
                for w in document["walls"]
            ),
            doors=tuple(Door(**{**d, "rooms": tuple(d["rooms"])}) for d in document["doors"]),
            landmarks=tuple(Landmark(**m) for m in document["landmarks"]),
        )


_PARTS = ("rooms", "walls", "doors", "landmarks")


# -- generation --------------------------------------------------------------------------------


def generate_building(
    rng: random.Random,
    rooms: int,
    *,
    layout: str = "grid",
    room_size_m: tuple[float, float] = (4.0, 8.0),
    corridor_width_m: tuple[float, float] = (1.8, 2.6),
    door_width_m: float = 1.0,
    extra_door_prob: float = 0.25,
    landmark_spacing_m: tuple[float, float] = (0.6, 1.2),
) -> Building:
    """Draw a building of ``rooms`` offices.

    Layouts: ``grid`` puts the offices in two rows that open into each other (a random
    spanning tree of doors, plus each other shared wall with ``extra_door_prob``);
    ``corridor`` puts them on both sides of a corridor (one more room, the last index) with a
    door each, and neighbouring offices joined with ``extra_door_prob``.
    """
    if rooms < 1:
        msg = f"a building needs at least one room, got rooms={rooms}"
        raise ValueError(msg)
    if layout not in LAYOUTS:
        msg = f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}"
        raise ValueError(msg)
    if min(room_size_m) < door_width_m + 2 * DOOR_MARGIN_M:
        msg = f"rooms of {min(room_size_m)} m cannot hold a door of {door_width_m} m"
        raise ValueError(msg)
    cols = (rooms + 1) // 2 if rooms > 1 else 1
    widths = [rng.uniform(*room_size_m) for _ in range(cols)]
    # cells[r][c]: the room filling grid cell (row r, column c), None where there is none
    if layout == "grid":
        heights = [rng.uniform(*room_size_m) for _ in range(2 if rooms > 1 else 1)]
        cells = [[_below(r * cols + c, rooms) for c in range(cols)] for r in range(len(heights))]
    else:
        heights = [rng.uniform(*room_size_m), rng.uniform(*corridor_width_m)]
        heights.append(rng.uniform(*room_size_m))
        cells = [[_below(c, rooms) for c in range(cols)], [rooms] * cols]
        cells.append([_below(cols + c, rooms) for c in range(cols)])
    xs, ys = _edges(widths), _edges(heights)
    spans: dict[int, list[int]] = {}  # room -> [c0, r0, c1, r1], the cells it covers
    for r, row in enumerate(cells):
        for c, index in enumerate(row):
            if index is not None:
                span = spans.setdefault(index, [c, r, c, r])
                span[2], span[3] = c, r
    room_list = tuple(
        Room(i, Rect(xs[c0], ys[r0], xs[c1 + 1], ys[r1 + 1]), "room" if i < rooms else "corridor")
        for i, (c0, r0, c1, r1) in sorted(spans.items())
    )
    pieces = _merge(_cell_walls(cells, xs, ys))
    doors = _doors(rng, pieces, layout, rooms, door_width_m, extra_door_prob)
    walls = _cut(pieces, doors)
    landmarks = _landmarks(rng, walls, landmark_spacing_m)
    return Building(rooms=room_list, walls=walls, doors=doors, landmarks=landmarks)


def _below(index: int, rooms: int) -> int | None:
    return index if index < rooms else None


def _edges(sizes: list[float]) -> list[float]:
    edges = [0.0]
    for size in sizes:
        edges.append(round(edges[-1] + size, 3))
    return edges


def _cell_walls(cells: list[list[int | None]], xs: list[float], ys: list[float]) -> Iterator[Wall]:
    """Yield a wall piece on every cell edge with different rooms (or outside) on its sides."""
    rows, cols = len(cells), len(cells[0])

    def at(r: int, c: int) -> int | None:
        return cells[r][c] if 0 <= r < rows and 0 <= c < cols else None

    for r in range(rows):
        for c in range(cols + 1):  # vertical edge: left cell (r, c-1), right cell (r, c)
            if at(r, c - 1) != at(r, c):
                yield Wall(xs[c], ys[r], xs[c], ys[r + 1], (at(r, c - 1), at(r, c)))
    for r in range(rows + 1):
        for c in range(cols):  # horizontal edge: cell below (r-1, c), cell above (r, c)
            if at(r - 1, c) != at(r, c):
                yield Wall(xs[c], ys[r], xs[c + 1], ys[r], (at(r - 1, c), at(r, c)))


def _merge(pieces: Iterator[Wall]) -> list[Wall]:
    """Join collinear, touching pieces with the same sides into one wall."""
    merged: list[Wall] = []
    for piece in sorted(
        pieces, key=lambda w: (w.vertical, w.x0 if w.vertical else w.y0, w.x0, w.y0)
    ):
        last = merged[-1] if merged else None
        if (
            last is not None
            and last.vertical == piece.vertical
            and last.sides == piece.sides
            and (last.x1, last.y1) == (piece.x0, piece.y0)
            and (last.x0 == piece.x0 if piece.vertical else last.y0 == piece.y0)
        ):
            merged[-1] = Wall(last.x0, last.y0, piece.x1, piece.y1, last.sides)
        else:
            merged.append(piece)
    return merged


def _doors(
    rng: random.Random, walls: list[Wall], layout: str, rooms: int, width: float, extra_prob: float
) -> tuple[Door, ...]:
    shared: dict[tuple[int, int], Wall] = {}
    for wall in walls:
        a, b = wall.sides
        if a is None or b is None:
            continue
        current = shared.get((a, b))
        if current is None or _length(wall) > _length(current):
            shared[(a, b)] = wall  # the longest stretch they share takes the door
    pairs = sorted(shared)
    rng.shuffle(pairs)
    if layout == "corridor":
        chosen = {p for p in pairs if rooms in p}
    else:  # random spanning tree (Kruskal over shuffled pairs) keeps every room reachable
        parent = list(range(rooms))

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        chosen = set()
        for a, b in pairs:
            if root(a) != root(b):
                parent[root(a)] = root(b)
                chosen.add((a, b))
    for pair in pairs:
        if pair not in chosen and rng.random() < extra_prob:
            chosen.add(pair)
    doors: list[Door] = []
    for pair in sorted(chosen):
        wall = shared[pair]
        lo = (wall.y0 if wall.vertical else wall.x0) + DOOR_MARGIN_M + width / 2
        hi = (wall.y1 if wall.vertical else wall.x1) - DOOR_MARGIN_M - width / 2
        at = round(rng.uniform(lo, hi), 3)
        x, y = (wall.x0, at) if wall.vertical else (at, wall.y0)
        doors.append(Door(len(doors), x, y, pair, width, wall.vertical))
    return tuple(doors)


def _length(wall: Wall) -> float:
    return abs(wall.x1 - wall.x0) + abs(wall.y1 - wall.y0)


def _cut(walls: list[Wall], doors: tuple[Door, ...]) -> tuple[Wall, ...]:
    """Cut each door's opening out of its wall."""
    out = []
    for wall in walls:
        lo, hi = (wall.y0, wall.y1) if wall.vertical else (wall.x0, wall.x1)
        gaps = sorted(
            ((door.y if door.vertical else door.x), door.width_m / 2)
            for door in doors
            if door.rooms == wall.sides and door.vertical == wall.vertical and _on(door, wall)
        )
        start = lo
        for centre, half in gaps:
            out.append(_span(wall, start, centre - half))
            start = centre + half
        out.append(_span(wall, start, hi))
    return tuple(out)


def _on(door: Door, wall: Wall) -> bool:
    if wall.vertical:
        return door.x == wall.x0 and wall.y0 < door.y < wall.y1
    return door.y == wall.y0 and wall.x0 < door.x < wall.x1


def _span(wall: Wall, a: float, b: float) -> Wall:
    if wall.vertical:
        return Wall(wall.x0, round(a, 3), wall.x0, round(b, 3), wall.sides)
    return Wall(round(a, 3), wall.y0, round(b, 3), wall.y0, wall.sides)


def _landmarks(
    rng: random.Random, walls: tuple[Wall, ...], spacing: tuple[float, float]
) -> tuple[Landmark, ...]:
    marks: list[Landmark] = []
    for wall in walls:
        lo, hi = (wall.y0, wall.y1) if wall.vertical else (wall.x0, wall.x1)
        for side, room in enumerate(wall.sides):
            if room is None:
                continue
            sign = -1.0 if side == 0 else 1.0  # normal points into the room on that side
            nx, ny = (sign, 0.0) if wall.vertical else (0.0, sign)
            at = lo + rng.uniform(0.05, spacing[0])
            while at < hi - 0.05:
                x, y = (wall.x0, at) if wall.vertical else (at, wall.y0)
                marks.append(Landmark(len(marks), round(x, 3), round(y, 3), room, nx, ny))
                at += rng.uniform(*spacing)
    return tuple(marks)

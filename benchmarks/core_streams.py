"""The synthetic streams of the core benchmark: a room chain and a visual stream.

Landmarks are tracked (``Tracker``); ``benchmarks.core_bench``'s docstring describes both
streams.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import NDArray

DOOR_FRAMES = 2  # frames at each side of a door that see both rooms
ENTRY_FRAMES = 3  # measured frames from a door on (its two frames and one more)


@dataclass(slots=True)
class Stream:
    """Frames (distinct feature IDs) and which of them are measured (observe, timed)."""

    name: str
    profile: str
    frames: list[NDArray[np.int64]] = field(default_factory=list)
    measured: list[bool] = field(default_factory=list)

    def add(self, features: NDArray[np.int64], measured: bool) -> None:
        """Append one frame."""
        self.frames.append(np.unique(features))
        self.measured.append(measured)


class Tracker:
    """Landmarks tracked over frames: each track lives 10-30 frames, then a new one starts."""

    def __init__(
        self, rng: np.random.Generator, pool: NDArray[np.int64], alive: int, life: tuple[int, int]
    ) -> None:
        """Start ``alive`` tracks on ``pool``, their ends staggered as if tracking had begun."""
        self._rng, self._life, self._frame = rng, life, 0
        self.tracks = rng.choice(pool, size=alive, replace=False)
        self._ends = rng.integers(1, life[1] + 1, size=alive)

    def _restart(self, which: NDArray[np.int64], pool: NDArray[np.int64]) -> None:
        free = np.setdiff1d(pool, self.tracks, assume_unique=True)
        self.tracks[which] = self._rng.choice(free, size=which.size, replace=False)
        self._ends[which] = self._frame + self._rng.integers(
            *self._life, endpoint=True, size=which.size
        )

    def cross(self, pool: NDArray[np.int64], share: float) -> None:
        """Move ``share`` of the tracks not on ``pool`` (the room left behind) onto it."""
        old = np.flatnonzero(~np.isin(self.tracks, pool))
        count = int(np.ceil(share * old.size))
        self._restart(self._rng.choice(old, size=count, replace=False), pool)

    def step(self, pool: NDArray[np.int64]) -> NDArray[np.int64]:
        """One frame: tracks that ended restart on ``pool``; return the frame's features."""
        done = np.flatnonzero(self._ends <= self._frame)
        if done.size:
            self._restart(done, pool)
        self._frame += 1
        return self.tracks.copy()


def room_chain(n: int, *, frames: int, features: int = 40, rooms: int = 3, seed: int = 0) -> Stream:
    """A walk through ``rooms`` rooms of ``n`` landmarks each (see ``benchmarks.core_bench``)."""
    rng = np.random.default_rng(seed * 100_003 + n)
    marks = rng.choice(10**9, size=rooms * n, replace=False).astype(np.int64).reshape(rooms, n)
    alive = min(features, int(0.7 * n))
    look_around = max(10, int(np.ceil(3 * n * 20 / alive)))  # ~3 tracks per landmark
    per_room = max(4, (frames - ENTRY_FRAMES * (rooms - 1)) // rooms)
    tracker = Tracker(rng, marks[0], alive, (10, 30))
    stream = Stream(name=f"room chain n={n}", profile="laser")
    for room in range(rooms):
        pool = marks[room]
        for t in range(ENTRY_FRAMES if room else 0):
            if t < DOOR_FRAMES:  # the door: half of the view, then the rest, is the new room
                tracker.cross(pool, 1.0 / (DOOR_FRAMES - t))
            stream.add(tracker.step(pool), measured=True)
        for _ in range(look_around):
            stream.add(tracker.step(pool), measured=False)
        for _ in range(per_room):
            stream.add(tracker.step(pool), measured=True)
    return stream


def visual(
    *,
    frames_per_room: int = 60,
    alive: int = 550,
    pool: int = 1200,
    rooms: int = 3,
    warmup: int = 15,
    seed: int = 0,
) -> Stream:
    """A stereo-tracking-like stream: ``alive`` tracks of 10-30 frames over room pools."""
    rng = np.random.default_rng(seed + 7919)
    marks = rng.choice(10**9, size=rooms * pool, replace=False).astype(np.int64)
    marks = marks.reshape(rooms, pool)
    tracker = Tracker(rng, marks[0], alive, (10, 30))
    stream = Stream(name=f"visual {alive}/frame", profile="stereo")
    door = frames_per_room - 10  # new tracks start on the next room from here on
    for t in range(rooms * frames_per_room):
        room = min(rooms - 1, (t + frames_per_room - door) // frames_per_room)
        stream.add(tracker.step(marks[room]), measured=t >= warmup)
    return stream

"""Hand-made streams for the AreaTracker rule tests, and a tracker run over one.

Every stream is a few "rooms" of landmark IDs seen with a fixed probability per frame
(seeded). Each test runs the stream with the defaults and with the one rule turned off or
changed, and asserts the difference, so a test fails when its rule stops working.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lessmap.core.areas.tracker import AreaParams, AreaTracker, AreaTransition

if TYPE_CHECKING:
    from collections.abc import Iterable

    from tests.core.helpers import Frames


A = frozenset(range(10))  # a room; also H1, one half of an open room
B = frozenset(range(100, 110))  # another room behind a door
H2 = frozenset(range(10, 20))  # the other half of the open room


def seen(rng: np.random.Generator, room: Iterable[int], p: float) -> list[int]:
    """The landmarks of ``room`` one frame sees, each with probability ``p``."""
    ids = np.asarray(sorted(room))
    return [int(i) for i in ids[rng.random(ids.size) < p]]


def stay(rng: np.random.Generator, room: Iterable[int], frames: int, p: float = 0.8) -> Frames:
    return [seen(rng, room, p) for _ in range(frames)]


def wide_door(rng: np.random.Generator, into: Iterable[int], left: Iterable[int]) -> Frames:
    """Ten frames in ``into`` that still see ``left`` behind, fading (a 360° sensor)."""
    return [seen(rng, into, 0.8) + seen(rng, left, 0.6 * (1 - k / 10)) for k in range(10)]


def track(
    frames: Frames, params: AreaParams | None = None
) -> tuple[AreaTracker, list[AreaTransition]]:
    tracker = AreaTracker(params)
    found = []
    for seq, frame in enumerate(frames):
        change = tracker.observe(seq, seq * 0.5, frame)
        if change is not None:
            found.append(change)
    return tracker, found


def moves(found: list[AreaTransition]) -> list[tuple[int, int]]:
    return [(change.left_area, change.area) for change in found]

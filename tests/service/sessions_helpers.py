"""Builders for the SessionTable tests: a table, frames and ends, a room walk, its queries.

No mocks and no Zenoh: the table is sans-IO, so these tests feed it real ``Frame`` and
``SessionEnd`` messages and compare what it decides with a standalone core ``Partitioner``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lessmap.core import PartitionParams
from lessmap.core.segmenter import Method
from lessmap.runtime.sessions import Identity, Outcome, Segmenting, SessionLimits, SessionTable
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap_schemas.messages import SessionState


FLEET = "fleet"
INSTANCE = "test-instance"
LASER = PartitionParams.from_profile("laser")

Message = tuple[str, str, Frame | SessionEnd]

# -- builders --------------------------------------------------------------------------------


def make_table(
    *,
    max_sessions: int = 8,
    max_nodes: int = 10_000,
    max_batch_frames: int = 1,
    idle_timeout_s: float = 60.0,
    params: PartitionParams = LASER,
) -> SessionTable:
    # The paper, as the offline `Partitioner` these tests compare with (areas sessions:
    # test_areas_sessions.py).
    return SessionTable(
        Segmenting(params=params, method=Method.PAPER),
        SessionLimits(
            max_sessions=max_sessions,
            max_nodes=max_nodes,
            max_batch_frames=max_batch_frames,
            idle_timeout_s=idle_timeout_s,
        ),
        identity=Identity(instance=INSTANCE),
    )


def frame(seq: int, features: Sequence[int] = (1, 2, 3), session: str = "s1") -> Frame:
    return Frame(session=session, seq=seq, stamp_s=float(seq), features=list(features))


def end(last_seq: int | None, session: str = "s1") -> SessionEnd:
    return SessionEnd(session=session, last_seq=last_seq, stamp_s=1000.0)


def msgs(robot: str, *messages: Frame | SessionEnd) -> list[Message]:
    return [(FLEET, robot, m) for m in messages]


def frames_at(*seqs: int, session: str = "s1", robot: str = "r1") -> list[Message]:
    return msgs(robot, *(frame(s, session=session) for s in seqs))


def codes(outcome: Outcome) -> list[ErrorCode]:
    return [r.code for r in outcome.rejections]


def state_of(table: SessionTable, robot: str = "r1") -> SessionState:
    state = table.state(FLEET, robot)
    assert state is not None
    return state


def room_walk(rooms: int = 2, *, stay: int = 30, seed: int | None = None) -> list[list[int]]:
    """Room k has features 10k..10k+9, seen for ``stay`` frames; between two rooms one door
    frame sees 10k+7..10k+12 (a small overlap). With a seed, each frame sees each feature of
    its room with probability 0.8 instead of all of them."""
    rng = np.random.default_rng(seed) if seed is not None else None
    frames: list[list[int]] = []
    for room in range(rooms):
        features = list(range(10 * room, 10 * room + 10))
        for _ in range(stay):
            seen = features if rng is None else [f for f in features if rng.random() < 0.8]
            frames.append(list(seen))
        if room + 1 < rooms:
            frames.append(list(range(10 * room + 7, 10 * room + 13)))
    return frames


def walk_frames(walk: Sequence[Sequence[int]], session: str = "s1") -> list[Frame]:
    return [frame(seq, features, session) for seq, features in enumerate(walk)]

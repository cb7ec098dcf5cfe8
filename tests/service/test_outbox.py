"""The outbox's ordering: checkpoints only after their transitions, never past a fenced one.

Real parts: a Zenoh router on loopback, the outbox on a session joined to it, a fleet app's
subscriber on another, a real session table and SQLite store. The fence is the outbox's
``epoch_for`` (the service passes ``Ownership.epoch_for``); here the test opens and closes it.
"""

from __future__ import annotations

import queue
import time
from typing import TYPE_CHECKING

from lessmap.core import PartitionParams
from lessmap.runtime.metrics import ServiceMetrics
from lessmap.runtime.outbox import EgressPolicy, Outbox
from lessmap.runtime.sessions import (
    DurabilityPolicy,
    Identity,
    Segmenting,
    SessionLimits,
    SessionTable,
)
from lessmap.runtime.store import CheckpointStore
from lessmap.sim.simulator import simulate
from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.messages import Frame, Transition

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import zenoh

FLEET, ROBOT = "fleet", "robot0"


def frames() -> list[Frame]:
    run = simulate(3, rooms=8, robots=1, frames_per_robot=400)
    return [
        Frame(session="s1", seq=f["seq"], stamp_s=f["stamp"], features=f["features"])
        for f in run.frames
    ]


def test_checkpoints_follow_their_transitions_and_stop_at_a_fenced_one(
    router: str, client_session: Callable[[str], zenoh.Session], tmp_path: Path
) -> None:
    fence_open = [True]
    store = CheckpointStore(tmp_path)
    store.open()
    metrics = ServiceMetrics()
    outbox = Outbox(
        client_session(router),
        metrics,
        instance="inst",
        policy=EgressPolicy(
            transition_cache=16,
            max_publishers=8,
            error_rate_per_s=10.0,
            error_burst=10,
        ),
        epoch_for=lambda _fleet, _robot: 3 if fence_open[0] else None,
        store=store,
    )
    table = SessionTable(
        Segmenting(params=PartitionParams.from_profile("laser")),
        SessionLimits(max_sessions=8, max_nodes=20_000, max_batch_frames=1, idle_timeout_s=3600.0),
        identity=Identity(instance="inst"),
        store=store,
        # A checkpoint with every frame, transitions included.
        durability=DurabilityPolicy(every_frames=1, phased=False),
    )
    got: queue.SimpleQueue[Transition] = queue.SimpleQueue()
    app = client_session(router)
    sub = app.declare_subscriber(
        keys.transitions(FLEET, ROBOT), lambda s: got.put(decode(s.payload.to_bytes(), Transition))
    )
    try:
        walk = frames()
        published: list[int] = []
        fenced_at: int | None = None
        saved: int | None = None  # seq of the last frame whose checkpoint was saved
        for index, frame in enumerate(walk):
            out = table.handle_batch([(FLEET, ROBOT, frame)], 0.0)
            assert [r.last_seq for _s, r in out.checkpoints] == [frame.seq]
            # The table saves nothing itself: the checkpoint waits for the outcome.
            record = store.load((FLEET, ROBOT))
            assert (None if record is None else record.last_seq) == saved
            if fenced_at is None and out.transitions and len(published) == 2:
                fence_open[0] = False  # the partition is handed over before this one is out
                fenced_at = index
            outbox.publish(out, 0.0)
            if fenced_at is not None:
                continue
            published += [c.transition.seq for _s, c in out.transitions]
            record = store.load((FLEET, ROBOT))
            assert record is not None
            assert record.last_seq == frame.seq
            saved = frame.seq
        assert fenced_at is not None, "the walk has at least three transitions"
        # Nothing at or after the fenced transition was saved: the next owner resumes before
        # it and decides it again.
        assert store.flush()
        record = store.load((FLEET, ROBOT))
        assert record is not None
        assert record.last_seq == saved
        assert saved == walk[fenced_at - 1].seq
        withheld = metrics.registry.get_sample_value("lessmap_checkpoints_withheld_total")
        assert withheld == len(walk) - fenced_at  # the fenced frame's and every later one
        seen: list[int] = []
        deadline = time.monotonic() + 10.0
        while len(seen) < len(published) and time.monotonic() < deadline:
            try:
                seen.append(got.get(timeout=0.2).seq)
            except queue.Empty:
                continue
        assert seen == published  # every transition before the fence reached the app
    finally:
        sub.undeclare()
        store.close()

"""A restart loses nothing: SIGTERM or kill -9 mid-stream, a new process on the same state.

Real processes on loopback: a Zenoh router opened by the test, two ``lessmap serve``
processes one after the other (peers of that router, sharing the test's state directory),
one robot replaying DLR, one fleet app. The reference is ``lessmap segment`` of the file,
for the paper and for the default method, areas (whose area ids and revisits must survive the
restart as exactly as the paper's transitions).
The frames the robot sends while no instance runs, and after a kill -9 those since the last
checkpoint, come back from the robot's publication cache (the service's catch-up query).
"""

from __future__ import annotations

import re
import signal
import threading
import time
from typing import TYPE_CHECKING, Any

import pytest
import zenoh

from lessmap.core import PartitionParams
from lessmap.core.segmenter import Method, make_segmenter
from lessmap.files.frames import read_frames
from lessmap_client import FleetClient, RobotPublisher
from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.messages import Error, Transition
from tests.conftest import ServeProcess, dataset, wait_until
from tests.service.test_serve_e2e import as_record, drain, offline_transitions, wait_closed

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.files.frames import FrameRow

pytestmark = pytest.mark.timeout(300)


def offline_area_changes(frames: list[FrameRow]) -> list[dict[str, Any]]:
    """One robot's transitions under the areas method, deciding at every frame."""
    segmenter = make_segmenter(Method.AREAS, PartitionParams.from_profile("laser"))
    found = []
    for frame in frames:
        segmenter.apply(frame.seq, frame.stamp_s, frame.features)
        found += [
            {
                "seq": c.transition.seq,
                "boundary_seq": c.transition.boundary_seq,
                "reason": c.reason,
                "closed": list(c.transition.closed.features),
                "opened": list(c.transition.opened.features),
                "area": c.area,
                "left_area": c.left_area,
                "revisit": c.revisit_of is not None,
            }
            for c in segmenter.decide()
        ]
    return found


def as_area_record(t: Transition) -> dict[str, Any]:
    return {
        "seq": t.seq,
        "boundary_seq": t.boundary_seq,
        "reason": t.reason,
        "closed": t.closed.features,
        "opened": t.opened.features,
        "area": t.area,
        "left_area": t.left_area,
        "revisit": t.revisit,
    }


# The paper only: for areas the kill -9 case below, with a catch-up, is the stricter test
# (the default test run stays short).
def test_sigterm_and_restart_resume_every_session_exactly(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    expected = offline_transitions(frames)["0"]
    half = len(frames) // 2
    options = ("-m", "peer", "-e", router, "--max-batch-frames", "1", "--method", "paper")
    session = client_session(router)
    with FleetClient(fleet_name, session=session) as client:
        robot = RobotPublisher(fleet_name, "dlr", session=session)
        first = serve(*options)
        assert robot.wait_for_service(20.0), first.log()
        for frame in frames[:half]:
            robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)

        def applied(count: int) -> Callable[[], bool]:
            def check() -> bool:
                state = client.state("dlr", fleet=fleet_name, timeout_s=2.0)
                return state is not None and state.frames_applied == count

            return check

        wait_until(applied(half), 60.0, "the first half applied")
        first.process.send_signal(signal.SIGTERM)
        assert first.process.wait(15) == 0, first.log()
        assert "session checkpoints in" in first.log()

        second = serve(*options)
        assert robot.wait_for_service(20.0), second.log()
        wait_until(lambda: "serving as" in second.log(), 20.0, "the second instance")
        for frame in frames[half:]:
            robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
        robot.close()
        state = wait_closed(client, fleet_name, "dlr", len(frames))
        got = drain(client)
        assert "session resumed from the state store" in second.log()

    assert state.frames_missing == state.frames_duplicate == state.frames_rejected == 0
    assert state.transitions == len(expected)
    # Submap ids continue across the restart, so no new event looks like an old one.
    closed_ids = [t.closed.id for t in got]
    assert closed_ids == sorted(set(closed_ids))
    assert [as_record(t) for t in got] == expected
    assert {t.instance for t in got} == {first.instance, second.instance}
    assert second.terminate() == 0


FRAMES_PER_S = 120.0  # paced: a 1000-frame cache spans ~8 s of it, the test's 3000 25 s


class PacedRobot:
    """Publishes frames at a steady rate from its own thread, whatever the service does.

    ``pause`` / ``resume`` hold it between two frames (the pace resumes from there), and it
    pauses by itself before frame ``hold_at``: a loaded machine may apply frames or start the
    next instance more slowly than the walk goes, and the test needs frames left for later.
    """

    def __init__(
        self, robot: RobotPublisher, frames: list[FrameRow], hold_at: int | None = None
    ) -> None:
        self.robot = robot
        self.frames = frames
        self.hold_at = hold_at
        self.sent = 0
        self._stop = threading.Event()
        self._running = threading.Event()
        self._running.set()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def pause(self) -> None:
        self._running.clear()

    def resume(self) -> None:
        self.hold_at = None  # held once at most: a resume before it lifts the hold too
        self._running.set()

    def _run(self) -> None:
        started = time.monotonic()
        for index, frame in enumerate(self.frames):
            if index == self.hold_at:
                self._running.clear()
            if not self._running.is_set():
                paused = time.monotonic()
                while not self._running.wait(0.05):
                    if self._stop.is_set():
                        return
                started += time.monotonic() - paused
            delay = started + index / FRAMES_PER_S - time.monotonic()
            if self._stop.wait(max(0.0, delay)):
                return
            self.robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
            self.sent = index + 1

    def join(self, timeout_s: float) -> None:
        self._thread.join(timeout_s)
        assert not self._thread.is_alive(), "the robot did not finish publishing"

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10.0)


@pytest.mark.parametrize(
    ("how", "method"),
    [
        (signal.SIGKILL, Method.PAPER),
        (signal.SIGTERM, Method.PAPER),
        (signal.SIGKILL, Method.AREAS),
    ],
    ids=["kill-9", "sigterm", "kill-9-areas"],
)
@pytest.mark.slow
def test_a_restart_mid_stream_catches_up_from_the_robots_cache(
    how: signal.Signals,
    method: Method,
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    if method is Method.PAPER:
        expected = offline_transitions(frames)["0"]
        record = as_record
    else:
        expected = offline_area_changes(frames)
        record = as_area_record
        assert any(change["revisit"] for change in expected)  # the areas' own fields matter
    # Checkpoints every 300 frames and only by count (the 10 s clock could land one at any
    # seq on a slow machine): the robot holds after 1250 frames and the kill comes once they
    # are applied, after the last checkpoint (seq 1199), so the frames between it and the crash,
    # which the dead process had applied and whose transitions it had published, must come
    # back from the cache too.
    # The rule a site sizes by: checkpoint interval + rate x downtime <= min(robot cache,
    # catch-up frames). A busy CI machine can take 10 s to restart the service (120 frames/s
    # x 10 s): cache and catch-up are sized for that, and the cache gets time to answer
    # (with the 1000-frame defaults a slow restart rightly reported frames as missing).
    options = (
        *("-m", "peer", "-e", router, "--max-batch-frames", "1", "--method", method.value),
        *("--checkpoint-every-frames", "300", "--checkpoint-interval-s", "3600"),
        *("--catchup-max-frames", "3000", "--catchup-wait-s", "10"),
    )
    session = client_session(router)
    raw: list[Transition] = []
    errors: list[Error] = []
    lock = threading.Lock()

    def keep(
        box: list[Transition] | list[Error], kind: type[Transition] | type[Error]
    ) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                box.append(decode(sample.payload.to_bytes(), kind))  # type: ignore[arg-type]

        return on_sample

    raw_sub = session.declare_subscriber(keys.transitions(fleet_name, "dlr"), keep(raw, Transition))
    error_sub = session.declare_subscriber(keys.errors(fleet_name, "dlr"), keep(errors, Error))
    with FleetClient(fleet_name, session=session) as client:
        robot = RobotPublisher(fleet_name, "dlr", session=session, cache=3000)
        first = serve(*options)
        assert robot.wait_for_service(20.0), first.log()
        paced = PacedRobot(robot, frames, hold_at=1250)
        paced.start()
        try:
            applied_before = [0]

            def applied_at_least(count: int) -> bool:
                state = client.state("dlr", fleet=fleet_name, timeout_s=2.0)
                applied_before[0] = 0 if state is None else state.frames_applied
                return applied_before[0] >= count

            wait_until(lambda: applied_at_least(1250), 60.0, "1250 frames applied")
            assert applied_before[0] == paced.sent == 1250  # held there: the kill finds 1250
            first.process.send_signal(how)
            code = first.process.wait(15)
            assert code == (-signal.SIGKILL if how == signal.SIGKILL else 0), first.log()
            stopped_at = paced.sent
            paced.resume()  # from its hold
            time.sleep(2.0)  # no instance runs; the robot goes on publishing
            paced.pause()  # frames are left for after the restart, however long it takes
            second = serve(*options)
            wait_until(lambda: "serving as" in second.log(), 60.0, "the second instance")
            assert paced.sent < len(frames), "the robot finished before the restart"
            paced.resume()
            paced.join(120.0)
        finally:
            paced.stop()
        robot.close()
        state = wait_closed(client, fleet_name, "dlr", len(frames))
        got = drain(client)
    raw_sub.undeclare()
    error_sub.undeclare()

    log = second.log()
    resumed = re.search(r"session resumed from the state store: .* at seq (\d+)", log)
    assert resumed is not None, log
    if how == signal.SIGKILL:
        assert int(resumed.group(1)) + 1 < applied_before[0]  # applied, then lost with it
    else:
        assert int(resumed.group(1)) + 1 >= applied_before[0]  # checkpointed at the stop
    recovered = re.search(r"(\d+) frame\(s\) recovered from the robot's cache", log)
    assert recovered is not None, log
    assert int(recovered.group(1)) > 100
    assert paced.sent - stopped_at > 100  # the downtime really spanned frames
    assert (state.frames_applied, state.frames_missing) == (len(frames), 0)
    # Exact accounting across the restart: every frame the robot put once is counted once
    # (cache redeliveries the service did not need are not robot puts and count nowhere).
    assert (state.frames_duplicate, state.frames_rejected) == (0, 0)
    assert state.transitions == len(expected)
    assert not [e for e in errors if e.code.value == "SEQ_GAP"], errors
    # De-duplicated on (session, closed id) as the client does: exactly the offline ones.
    assert [record(t) for t in got] == expected
    # A transition published twice (before the kill and again after the catch-up) is the
    # same transition: nothing conflicting ever reached the wire.
    by_id: dict[tuple[str, int], list[dict[str, object]]] = {}
    for t in raw:
        by_id.setdefault((t.session, t.closed.id), []).append(record(t))
    assert all(all(r == records[0] for r in records) for records in by_id.values())
    assert sorted(by_id) == [(state.session, i) for i in range(len(expected))]
    assert second.terminate() == 0


def test_after_a_restart_every_stored_robot_is_answered_before_it_sends_again(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    router: str,
    fleet_name: str,
) -> None:
    # One robot ended its session, one is between frames: neither is in the new process's
    # memory until it sends again, yet state, areas and submaps queries must find both.
    frames = list(read_frames(dataset("dlr.frames.jsonl")))[:40]
    options = ("-m", "peer", "-e", router, "--max-batch-frames", "1")
    session = client_session(router)
    first = serve(*options)
    with FleetClient(fleet_name, session=session) as client:
        done, pausing = (RobotPublisher(fleet_name, name, session=session) for name in "ab")
        assert done.wait_for_service(20.0), first.log()
        for frame in frames:
            for robot in (done, pausing):
                robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
        done.close()
        wait_closed(client, fleet_name, "a", len(frames))
        wait_until(
            lambda: {s.robot: s.frames_applied for s in client.states()} == {"a": 40, "b": 40},
            60.0,
            "both robots' frames applied",
        )
        before = {s.robot: s for s in client.states()}
        graphs_before = {g.robot: g for g in client.area_graphs()}
        first.process.send_signal(signal.SIGTERM)
        assert first.process.wait(15) == 0, first.log()

        second = serve(*options)
        wait_until(lambda: "serving as" in second.log(), 30.0, "the second instance")
        wait_until(lambda: len(client.states()) == 2, 30.0, "both robots answered", second.log)
        after = {s.robot: s for s in client.states()}
        assert {r: (s.session, s.open, s.frames_applied) for r, s in after.items()} == {
            r: (s.session, s.open, s.frames_applied) for r, s in before.items()
        }
        assert (after["a"].open, after["b"].open) == (False, True)
        assert client.state("b", fleet=fleet_name) == after["b"]
        graphs_after = {g.robot: g for g in client.area_graphs()}
        assert {r: (g.session, g.areas, g.passages) for r, g in graphs_after.items()} == {
            r: (g.session, g.areas, g.passages) for r, g in graphs_before.items()
        }
        assert [s.summary.id for s in client.submaps("a", fleet=fleet_name)] == [
            s.id for s in [*after["a"].closed_submaps, after["a"].current_submap]
        ]
        pausing.close(timeout_s=0)

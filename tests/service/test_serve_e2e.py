"""End to end: a real ``lessmap serve`` subprocess, real Zenoh on loopback, real clients."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

import msgpack
import pytest
import zenoh

from lessmap.cli.segment import segment
from lessmap.core import PartitionParams
from lessmap.files.frames import FrameRow, read_frames
from lessmap_client import FleetClient, RobotPublisher
from lessmap_client.session import wait_for_service
from lessmap_schemas import keys
from lessmap_schemas.codec import decode, encode
from lessmap_schemas.errors import InvalidNameError
from lessmap_schemas.messages import Error, Frame, SessionState, Transition
from lessmap_schemas.partition import PARTITIONS, owner_and_standby, partition_of
from tests.conftest import ServeProcess, dataset, metric_value, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable
    from pathlib import Path

pytestmark = pytest.mark.timeout(240)


def offline_transitions(frames: Iterable[FrameRow]) -> dict[str, list[dict[str, Any]]]:
    """Per robot, the transitions ``lessmap segment --method paper`` computes (laser profile)."""
    found: dict[str, list[dict[str, Any]]] = {}

    def keep(robot: str, t: Any) -> None:
        found.setdefault(robot, []).append(
            {
                "seq": t.seq,
                "boundary_seq": t.boundary_seq,
                "reason": str(t.reason),
                "ncut": t.ncut,
                "lambda2": t.lambda2,
                "closed": list(t.closed.features),
                "opened": list(t.opened.features),
            }
        )

    segment(frames, PartitionParams.from_profile("laser"), on_transition=keep)
    return found


def as_record(t: Transition) -> dict[str, Any]:
    return {
        "seq": t.seq,
        "boundary_seq": t.boundary_seq,
        "reason": t.reason,
        "ncut": t.ncut,
        "lambda2": t.lambda2,
        "closed": t.closed.features,
        "opened": t.opened.features,
    }


def drain(client: FleetClient, quiet_s: float = 1.0) -> list[Transition]:
    got = []
    while (t := client.next_transition(timeout_s=quiet_s)) is not None:
        got.append(t)
    return got


def wait_closed(client: FleetClient, fleet: str, robot: str, frames: int) -> SessionState:
    """Wait until the robot's (last) session is closed with every frame applied."""
    box: list[SessionState] = []

    def done() -> bool:
        state = client.state(robot, fleet=fleet, timeout_s=2.0)
        if state is not None and not state.open and state.frames_applied == frames:
            box.append(state)
            return True
        return False

    wait_until(done, 120.0, f"{fleet}/{robot} to apply {frames} frames and close")
    return box[0]


def start_service(
    serve: Callable[..., ServeProcess],
    *extra: str,
    metrics: bool = False,
    method: str | None = "paper",
) -> ServeProcess:
    # max-batch-frames 1: decide at every frame, whatever the pace, so results are comparable
    # with the offline run bit for bit. The paper unless told otherwise: these tests compare
    # with `offline_transitions`, the paper's partitioner; None runs the service's default.
    chosen = () if method is None else ("--method", method)
    return serve("--max-batch-frames", "1", *chosen, *extra, metrics=metrics)


def test_dlr_replay_equals_offline_segment(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    expected = offline_transitions(frames)["0"]
    service = start_service(serve)
    session = client_session(service.endpoint)
    with FleetClient(fleet_name, session=session) as client:
        with RobotPublisher(fleet_name, "dlr", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            for frame in frames:
                robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
        state = wait_closed(client, fleet_name, "dlr", len(frames))
        got = drain(client)
    assert state.transitions == len(expected)
    assert [as_record(t) for t in got] == expected
    assert {t.instance for t in got} == {service.instance}
    assert all(t.batch_frames == 1 for t in got)
    assert service.terminate() == 0


def test_five_robots_and_a_session_restart_match_offline(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("mrclam6.frames.jsonl")))
    robots = sorted({f.robot for f in frames})
    assert len(robots) == 5
    restarted = robots[0]
    rerun = [f for f in frames if f.robot == restarted][:300]
    expected = offline_transitions(frames)
    expected_rerun = offline_transitions(rerun)[restarted]

    service = start_service(serve, "--shards", "2")
    session = client_session(service.endpoint)
    with FleetClient(fleet_name, session=session) as client:
        publishers = {r: RobotPublisher(fleet_name, f"r{r}", session=session) for r in robots}
        assert publishers[restarted].wait_for_service(20.0), service.log()
        for frame in frames:  # interleaved by stamp, as the robots ran
            publishers[frame.robot].publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
        first_session = publishers[restarted].session_id
        publishers[restarted].close()
        # The robot restarts: a new session id, a new CovGraph, seqs from 0 again.
        with RobotPublisher(fleet_name, f"r{restarted}", session=session) as again:
            for frame in rerun:
                again.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
            second_session = again.session_id
        for robot, publisher in publishers.items():
            publisher.close()
            if robot != restarted:
                wait_closed(client, fleet_name, f"r{robot}", sum(f.robot == robot for f in frames))
        wait_closed(client, fleet_name, f"r{restarted}", len(rerun))
        got = drain(client)

    by_session: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for t in got:
        assert t.fleet == fleet_name
        by_session.setdefault((t.robot, t.session), []).append(as_record(t))
    for robot in robots:
        if robot == restarted:
            continue
        sessions = [s for (r, s) in by_session if r == f"r{robot}"]
        assert len(sessions) == 1, f"robot {robot}: {sessions}"
        assert by_session[(f"r{robot}", sessions[0])] == expected[robot], f"robot {robot}"
    assert by_session[(f"r{restarted}", first_session)] == expected[restarted]
    assert by_session.get((f"r{restarted}", second_session), []) == expected_rerun
    assert service.terminate() == 0


def raw_put(session: zenoh.Session, key: str, payload: bytes) -> None:
    # Block, never drop: with Zenoh's default (drop under congestion) a loaded machine lost
    # some 2 MiB puts before they reached the service, and the counts below came out short.
    session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)


REJECTED = "lessmap_frames_rejected_total"


def test_hostile_input_is_rejected_and_the_good_robot_is_unaffected(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))[:1500]
    expected = offline_transitions(frames)["0"]
    service = start_service(serve, metrics=True)
    session = client_session(service.endpoint)
    errors: list[Error] = []
    lock = threading.Lock()

    def on_error(sample: zenoh.Sample) -> None:
        with lock:
            errors.append(decode(sample.payload.to_bytes(), Error))

    error_sub = session.declare_subscriber(keys.errors(fleet_name, "*"), on_error)
    service_error_sub = session.declare_subscriber(keys.service_errors("*"), on_error)
    evil = keys.frames(fleet_name, "evil")
    good_frame = Frame(session="s1", seq=0, stamp_s=0.0, features=[1, 2]).model_dump()

    def hostile() -> None:
        for round_ in range(20):
            raw_put(session, evil, b"\xc1 not msgpack")
            raw_put(session, evil, msgpack.packb([1, 2, 3]))
            raw_put(session, evil, msgpack.packb({**good_frame, "seq": "seven"}))
            raw_put(session, evil, msgpack.packb({**good_frame, "features": list(range(5000))}))
            raw_put(session, evil, b"\x00" * (2 * 1024 * 1024))
            # A name that breaks the rule (on the partition its name hashes to), and a good
            # name on another robot's partition: both BAD_NAME.
            part = partition_of(fleet_name, "bad robot")
            bad_name = f"{keys.KEY_PREFIX}/{fleet_name}/bad robot/frames/{part}"
            wrong = (partition_of(fleet_name, "evil") + 1) % PARTITIONS
            wrong_partition = f"{keys.KEY_PREFIX}/{fleet_name}/evil/frames/{wrong}"
            for key in (bad_name, wrong_partition):
                raw_put(
                    session,
                    key,
                    encode(Frame(session="s1", seq=round_, stamp_s=0.0, features=[1])),
                )
            # A replaying robot: every frame twice, then one from the past.
            for seq in (3 * round_, 3 * round_ + 2, 3 * round_ + 2, 3 * round_ + 1):
                replayed = Frame(session="s1", seq=seq, stamp_s=0.0, features=[seq, 1])
                raw_put(session, keys.frames(fleet_name, "replayer"), encode(replayed))

    with pytest.raises(InvalidNameError):
        keys.frames(fleet_name, "ro*bot")  # a wildcard name never reaches the wire
    with FleetClient(fleet_name, "good", session=session) as client:
        with RobotPublisher(fleet_name, "good", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            attacker = threading.Thread(target=hostile)
            attacker.start()
            for frame in frames:
                robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
            attacker.join(60)
        wait_closed(client, fleet_name, "good", len(frames))
        got = drain(client)
        # A second attack once the good robot's session is built and the solver's modules are
        # loaded: what RSS gains now is what the hostile traffic left behind.
        rss_before = service.rss_kib()
        hostile()
        wait_until(
            lambda: metric_value(service.metrics(), REJECTED, reason="LIMIT_EXCEEDED") >= 80,
            20.0,
            "the second attack rejected",
        )
    needed = {"MALFORMED", "INVALID", "LIMIT_EXCEEDED", "BAD_NAME", "DUPLICATE_SEQ"}
    wait_until(
        lambda: needed <= {e.code.value for e in errors},
        20.0,
        f"errors of every kind, got {sorted({e.code.value for e in errors})}",
    )
    error_sub.undeclare()
    service_error_sub.undeclare()

    assert [as_record(t) for t in got] == expected
    assert service.process.poll() is None, "the daemon died"
    assert all(e.robot in (None, "evil", "replayer") for e in errors)
    metrics = service.metrics()
    assert metric_value(metrics, "lessmap_frames_rejected_total", reason="MALFORMED") >= 20
    assert metric_value(metrics, REJECTED, reason="LIMIT_EXCEEDED") >= 80
    assert metric_value(metrics, "lessmap_frames_rejected_total", reason="BAD_NAME") >= 20
    assert metric_value(metrics, "lessmap_frames_duplicate_total") >= 20
    assert metric_value(metrics, "lessmap_transitions_total", reason="SPECTRAL") > 0
    # Twenty 2 MiB payloads went by in the second attack: none may stay in memory.
    assert service.rss_kib() - rss_before < 16 * 1024
    assert service.terminate() == 0


@pytest.mark.parametrize("durable", [True, False], ids=["durable", "memory-only"])
def test_sigterm_during_replay_exits_zero_and_publishes_final_state(
    durable: bool,
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    service = start_service(serve, *(() if durable else ("--memory-only",)))
    session = client_session(service.endpoint)
    finals: list[SessionState] = []
    state_sub = session.declare_subscriber(
        keys.state(fleet_name, "r0"),
        lambda sample: finals.append(decode(sample.payload.to_bytes(), SessionState)),
    )
    robot = RobotPublisher(fleet_name, "r0", session=session)
    assert robot.wait_for_service(20.0), service.log()
    published = 0
    for frame in frames[:1000]:
        robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
        published += 1
    stopped = time.monotonic()
    service.process.send_signal(signal.SIGTERM)
    # keep publishing while the service stops: it must not hang on it
    for frame in frames[1000:1200]:
        robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
    code = service.process.wait(15)
    elapsed = time.monotonic() - stopped
    assert code == 0, service.log()
    assert elapsed < 10.0
    wait_until(lambda: bool(finals), 5.0, "the final state")
    final = finals[-1]
    # A stop with a state store suspends the session (a restart resumes it); memory-only
    # it is the session's end.
    assert final.open is durable
    assert final.session == robot.session_id
    # everything queued before SIGTERM applied
    assert final.frames_applied >= published - 1, service.log()
    assert "stopped" in service.log()
    state_sub.undeclare()
    robot.close()


def test_a_taken_port_is_a_one_line_error(serve: Callable[..., ServeProcess]) -> None:
    first = serve()
    wait_until(lambda: "serving as" in first.log(), 30.0, "the first service to start")
    port = first.endpoint.rsplit(":", 1)[1]
    second = subprocess.run(
        # memory-only: the state directory is the first one's (one instance per directory)
        [
            sys.executable,
            "-m",
            "lessmap",
            "serve",
            "-m",
            "router",
            "-l",
            first.endpoint,
            "--memory-only",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert second.returncode == 1
    # Checked before the service opens anything: one line, which names the flag to change.
    assert second.stderr.splitlines() == [
        f"lessmap serve: cannot listen on tcp/127.0.0.1:{port}: the port is already in use; "
        "stop the program that holds it or choose another port with -l/--listen"
    ]
    assert first.terminate() == 0


@pytest.mark.parametrize("subscription", ["all", "partitions"])
@pytest.mark.slow
def test_two_instances_split_a_fleet_by_partition(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    tmp_path: Path,
    subscription: str,
) -> None:
    fleet = "split"
    frames = list(read_frames(dataset("mrclam6.frames.jsonl")))[:2500]
    robots = sorted({f.robot for f in frames})
    expected = offline_transitions(frames)

    def owners(names: list[str]) -> dict[str, str | None]:
        return {f"r{r}": owner_and_standby(partition_of(fleet, f"r{r}"), names)[0] for r in robots}

    # Fixed names that give each instance some of the five robots (random ones may not).
    names = next(
        [f"split-a{i}", f"split-b{i}"]
        for i in range(100)
        if len(set(owners([f"split-a{i}", f"split-b{i}"]).values())) == 2
    )
    owner_of = owners(names)
    mode = ("--frames-subscription", subscription)
    first = start_service(
        serve, "--instance", names[0], "--state-dir", str(tmp_path / "a"), *mode, metrics=True
    )
    session = client_session(first.endpoint)

    def logs() -> str:
        return "\n".join(f"--- {p.instance}:\n{p.log()[-3000:]}" for p in (first, second))

    # The second joins a running first one (a router that is not listening yet would be
    # retried only after Zenoh's back-off).
    assert wait_for_service(session, 60.0), first.log()[-3000:]
    second = start_service(
        serve,
        "-e",
        first.endpoint,
        "--instance",
        names[1],
        "--state-dir",
        str(tmp_path / "b"),
        *mode,
        metrics=True,
    )
    with FleetClient(fleet, session=session) as client:
        seen: list[list[str]] = []

        def both_alive() -> bool:
            seen.append(client.instances())
            return len(seen[-1]) == 2

        wait_until(
            both_alive, 60.0, "both instances to be alive", lambda: f"saw {seen[-3:]}\n{logs()}"
        )

        def owned(proc: ServeProcess) -> float:
            try:
                return metric_value(proc.metrics(), "lessmap_partitions_owned")
            except OSError:
                return 0.0  # the metrics server is not up yet

        wait_until(
            lambda: (
                min(owned(first), owned(second)) > 0 and owned(first) + owned(second) == PARTITIONS
            ),
            30.0,
            "the partitions to be shared out",
        )
        publishers = {r: RobotPublisher(fleet, f"r{r}", session=session) for r in robots}
        for frame in frames:
            publishers[frame.robot].publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
        for robot, publisher in publishers.items():
            publisher.close()
            wait_closed(client, fleet, f"r{robot}", sum(f.robot == robot for f in frames))
        got = drain(client)
        states = client.states()
    assert sorted(s.robot for s in states) == [f"r{r}" for r in robots]  # one answer each
    assert {s.robot: s.instance for s in states} == owner_of
    assert set(owner_of.values()) == set(names), "both instances should serve someone"
    for robot in robots:
        mine = [t for t in got if t.robot == f"r{robot}"]
        assert [as_record(t) for t in mine] == expected.get(robot, []), robot
        assert {t.instance for t in mine} <= {owner_of[f"r{robot}"]}
    # Each instance took its own robots' frames only (frames and session ends): Zenoh routed
    # it nothing else ("partitions"), or it left the others' frames to their owner ("all").
    everything = len(frames) + len(robots)
    for proc, name in ((first, names[0]), (second, names[1])):
        text = proc.metrics()
        own = sum(
            1 + sum(f.robot == r for f in frames) for r in robots if owner_of[f"r{r}"] == name
        )
        assert own > 0
        assert metric_value(text, "lessmap_frames_received_total") == own, name
        foreign = everything - own if subscription == "all" else 0
        assert metric_value(text, "lessmap_frames_foreign_total") == foreign, name
    assert second.terminate() == 0
    assert first.terminate() == 0

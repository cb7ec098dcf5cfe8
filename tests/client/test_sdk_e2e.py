"""The SDK and the client commands against a real ``lessmap serve`` on loopback."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from typing import TYPE_CHECKING

import pytest

from lessmap.core import PartitionParams
from lessmap.core.segmenter import make_segmenter
from lessmap_client import FleetClient, RobotPublisher
from lessmap_schemas.errors import InvalidNameError, WireError
from tests.conftest import REPO, ServeProcess, free_port, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import zenoh

    from lessmap_schemas.messages import Transition

pytestmark = pytest.mark.timeout(180)


def two_room_walk(rooms: int = 3, per_room: int = 30) -> list[list[int]]:
    """Frames of a robot crossing ``rooms`` rooms of 10 landmarks each, doors in between."""
    frames = []
    for room in range(rooms):
        ids = list(range(room * 10, room * 10 + 10))
        for step in range(per_room):
            frames.append([f for i, f in enumerate(ids) if (i + step) % 4 != 0])
        if room + 1 < rooms:
            frames.append([ids[-1], ids[-2], (room + 1) * 10, (room + 1) * 10 + 1])
    return frames


def offline_seqs(frames: list[list[int]]) -> list[int]:
    """Transition seqs of the service's default method (areas), deciding at every frame."""
    segmenter = make_segmenter("areas", PartitionParams.from_profile("laser"))
    seqs = []
    for seq, features in enumerate(frames):
        segmenter.apply(seq, 0.0, features)
        seqs += [change.transition.seq for change in segmenter.decide()]
    return seqs


@pytest.mark.slow
def test_round_trip_late_join_and_queries(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    walk = two_room_walk()
    expected = offline_seqs(walk)
    assert len(expected) == 2  # the walk itself is sound: two doors, two transitions
    service = serve("--max-batch-frames", "1")
    session = client_session(service.endpoint)
    live = FleetClient(fleet_name, session=session)
    callbacks = FleetClient(fleet_name, session=session)
    via_callback: list[Transition] = []
    callbacks.on_transition(via_callback.append)
    with RobotPublisher(fleet_name, "walker", session=session) as robot:
        assert robot.wait_for_service(20.0), service.log()
        for features in walk:
            robot.publish(features, stamp_s=0.0)
        session_id = robot.session_id
    received = [t for t in live.transitions(timeout_s=5.0)]
    live.close()
    assert [t.seq for t in received] == expected
    # Each callback has its own subscription: the client's own queue still holds them all.
    assert [t.seq for t in callbacks.transitions(timeout_s=5.0)] == expected
    wait_until(lambda: len(via_callback) == len(expected), 20.0, "the callback")
    callbacks.close()
    assert [t.seq for t in via_callback] == expected
    assert {(t.robot, t.session) for t in received} == {("walker", session_id)}

    # A fleet app that joins after the fact recovers the recent transitions from the cache.
    with FleetClient(fleet_name, session=session) as late:
        recovered = [late.next_transition(timeout_s=10.0) for _ in expected]
    assert [t.seq for t in recovered if t is not None] == expected

    with FleetClient(fleet_name, session=session, history=0) as fleet:
        state = fleet.state("walker")
        assert state is not None
        assert (state.open, state.frames_applied, state.transitions) == (False, len(walk), 2)
        submaps = fleet.submaps("walker")
        assert [s.summary.id for s in submaps] == [0, 1, 2]
        assert set(submaps[0].summary.features) >= set(range(10)) - {9}
        one = fleet.submap("walker", 1)
        assert one is not None
        assert one.summary == submaps[1].summary
        assert fleet.submap("walker", 99) is None
        assert fleet.state("nobody") is None
        assert [h.instance for h in fleet.health()] == [service.instance]
        assert service.instance in fleet.instances(timeout_s=5.0)
    assert service.terminate() == 0


@pytest.mark.slow
def test_apps_joining_a_two_instance_fleet_get_every_cached_transition(
    router: str,
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    # Two instances share the robots behind a router: a late app's history comes from two
    # publication caches at once (one query to both, and late-publisher detection beside
    # it), and no robot's older transitions may give way to its newer ones.
    walk = two_room_walk(rooms=20, per_room=20)
    expected = offline_seqs(walk)
    assert len(expected) == 19
    for _ in range(2):
        serve("--max-batch-frames", "1", "-e", router)
    session = client_session(router)
    robots = [f"r{i}" for i in range(4)]
    publishers = [RobotPublisher(fleet_name, robot, session=session) for robot in robots]
    try:
        assert all(p.wait_for_service(30.0) for p in publishers)
        for features in walk:
            for publisher in publishers:
                publisher.publish(features, stamp_s=0.0)
        with FleetClient(fleet_name, session=session, history=0) as queries:

            def all_applied() -> bool:
                states = [queries.state(robot) for robot in robots]
                return all(s is not None and s.frames_applied == len(walk) for s in states)

            wait_until(all_applied, 60.0, "every frame applied")
        for _ in range(3):
            with FleetClient(fleet_name, session=client_session(router)) as late:
                got: dict[str, list[int]] = {robot: [] for robot in robots}
                deadline = time.monotonic() + 30.0
                while any(len(seqs) < len(expected) for seqs in got.values()):
                    left = deadline - time.monotonic()
                    transition = late.next_transition(timeout_s=max(0.0, left))
                    if transition is None:
                        break
                    got[transition.robot].append(transition.seq)
            assert got == dict.fromkeys(robots, expected)
    finally:
        for publisher in publishers:
            publisher.close()


def test_publisher_checks_names_and_limits_locally(
    serve: Callable[..., ServeProcess], client_session: Callable[[str], zenoh.Session]
) -> None:
    service = serve()
    session = client_session(service.endpoint)
    with pytest.raises(InvalidNameError, match="robot"):
        RobotPublisher("fleet", "bad/robot", session=session)
    with RobotPublisher("fleet", "ok", session=session) as robot:
        with pytest.raises(WireError, match="max_features_per_frame"):
            robot.publish(range(5000))
        with pytest.raises(WireError):
            robot.publish([-1])
        assert robot.publish([1, 2]) == 0
        with pytest.raises(WireError):
            robot.publish([1], seq=0)  # already used
    with pytest.raises(RuntimeError, match="closed"):
        robot.publish([1])


def test_closing_never_hangs() -> None:
    # A quiet service: the client blocks in next_transition on one thread and closes from
    # another; both must return promptly.
    from lessmap_client.session import open_session

    port = free_port()
    router = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lessmap",
            "serve",
            "-m",
            "router",
            "-l",
            f"tcp/127.0.0.1:{port}",
            "--cfg",
            "scouting/multicast/enabled:false",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        session = open_session([f"tcp/127.0.0.1:{port}"], timeout_s=20.0)
        client = FleetClient("quiet", session=session)
        waiter_result: list[object] = []
        waiter = threading.Thread(target=lambda: waiter_result.append(client.next_transition()))
        waiter.start()
        time.sleep(0.2)
        started = time.monotonic()
        client.close()
        waiter.join(10.0)
        assert not waiter.is_alive()
        assert waiter_result == [None]
        client.close()  # idempotent
        session.close()
        assert time.monotonic() - started < 10.0
    finally:
        router.terminate()
        router.wait(10)


def run_cli(*args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lessmap", *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        cwd=REPO,
        check=False,
    )


def test_replay_command_delivers_every_frame(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    tmp_path: Path,
) -> None:
    walk = two_room_walk()
    path = tmp_path / "walk.frames.jsonl"
    lines = []
    for seq, features in enumerate(walk):
        for robot in ("a", "b"):
            lines.append(
                json.dumps(
                    {
                        "robot": robot,
                        "seq": seq,
                        "stamp": seq * 0.01,
                        "features": features,
                        "pose": None,
                    }
                )
            )
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    service = serve("--max-batch-frames", "1")
    done = run_cli("replay", str(path), "--fleet", fleet_name, "--fast", "-e", service.endpoint)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert (summary["frames"], summary["robots"], summary["applied"], summary["ok"]) == (
        2 * len(walk),
        2,
        2 * len(walk),
        True,
    )
    for name in ("a", "b"):
        counted = summary["per_robot"][name]
        assert (counted["offered"], counted["applied"], counted["missing"]) == (
            len(walk),
            len(walk),
            0,
        )
        assert counted["transitions"] == 2
    session = client_session(service.endpoint)
    with FleetClient(fleet_name, session=session) as fleet:

        def all_closed() -> bool:
            states = fleet.states()
            return len(states) == 2 and all(not s.open for s in states)

        wait_until(all_closed, 30.0, "both replayed sessions to close")
        for state in fleet.states():
            assert (state.frames_applied, state.frames_missing, state.transitions) == (
                len(walk),
                0,
                2,
            )


@pytest.mark.slow
def test_watch_command_shows_transitions(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    service = serve("--max-batch-frames", "1")
    watch = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lessmap",
            "watch",
            "--fleet",
            fleet_name,
            "--duration",
            "12",
            "-e",
            service.endpoint,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        session = client_session(service.endpoint)
        time.sleep(2.0)  # let the watcher subscribe (it also recovers history, but be live)
        with RobotPublisher(fleet_name, "seen", session=session) as robot:
            # Stamped by the SDK at publish time (the wall clock): the areas method reads
            # no stamp gap of a source not declared to leave out its empty frames, so a
            # stall of this process at a door costs no transition.
            for features in two_room_walk():
                robot.publish(features)
        out, err = watch.communicate(timeout=60)
    finally:
        if watch.poll() is None:
            watch.kill()
    assert watch.returncode == 0, err
    assert out.count(f"{fleet_name}/seen: area ") == 2, out
    assert "SPECTRAL" in out
    table = out.splitlines()[-3:]  # header, rule, one row
    assert table[0].startswith("robot")
    assert table[2].startswith(f"{fleet_name}/seen"[:24])


def test_sim_command_writes_frames_and_truth(tmp_path: Path) -> None:
    done = run_cli(
        "sim",
        "--out",
        str(tmp_path),
        "--rooms",
        "6",
        "--robots",
        "2",
        "--frames",
        "50",
        "--name",
        "b",
    )
    assert done.returncode == 0, done.stderr
    frames = (tmp_path / "b.frames.jsonl").read_text().splitlines()
    truth = (tmp_path / "b.truth.jsonl").read_text().splitlines()
    assert len(frames) == len(truth) == 100
    assert (tmp_path / "b.building.json").exists()
    assert run_cli("sim").returncode == 1  # nothing to do is an error, not a silent success


@pytest.mark.slow
def test_demo_command_runs_to_completion() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    done = run_cli("demo", "--duration", "10", "--listen", endpoint, "--json", timeout_s=150)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    robots = summary["robots"]
    assert len(robots) == 3
    for name, figures in robots.items():
        assert figures["frames_missing"] == 0, name
        assert figures["frames_applied"] > 0, name
        if figures["room_changes"]:
            assert figures["transitions"] > 0, name
    assert summary["score"]["transitions"] > 0

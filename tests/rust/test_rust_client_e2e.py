"""The Rust client (``clients/rust``) against a real ``lessmap serve``: the contract alone suffices.

The Rust examples run as processes on a loopback router: ``replay_frames`` streams the DLR
frames file through the Rust ``RobotPublisher`` and ``follow_fleet`` receives the transitions
through the Rust ``Subscription`` and queries the final ``SessionState``; the transitions must
be exactly those ``lessmap segment`` computes offline for the file. ``close_fleet`` ends a
fleet's sessions with the Rust ``close_all``: the service must hold every frame and close
every session, and with no service every end comes back unconfirmed at once. Skipped where
``cargo`` or the shared data sets are absent.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

import lessmap_client
from lessmap_schemas.partition import partition_of
from tests.conftest import REPO, ServeProcess, dataset, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

CRATE = REPO / "clients" / "rust"
EXAMPLES = ("close_fleet", "follow_fleet", "publish_walk", "replay_frames")

# A cold build of zenoh takes minutes on a small machine; scripts/check runs `cargo test`
# first, which builds the examples, so here the build is usually a no-op.
pytestmark = [pytest.mark.timeout(1800), pytest.mark.slow]


def cargo_target_dir() -> str:
    """The target directory scripts/check uses: one cache outside the repository."""
    if target := os.environ.get("CARGO_TARGET_DIR"):
        return target
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return str(Path(cache) / "lessmap" / "cargo-target")


@pytest.fixture(scope="module")
def examples() -> dict[str, Path]:
    """Build the Rust examples (a no-op when built) and return their executables by name."""
    cargo = shutil.which("cargo")
    if cargo is None:
        pytest.skip("cargo not found: the Rust client is not built here")
    env = {**os.environ, "CARGO_TARGET_DIR": cargo_target_dir()}
    result = subprocess.run(
        [cargo, "build", "--examples", "--message-format=json-render-diagnostics", "--quiet"],
        cwd=CRATE,
        env=env,
        capture_output=True,
        text=True,
        timeout=1500,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    found: dict[str, Path] = {}
    for line in result.stdout.splitlines():
        message = json.loads(line)
        target = message.get("target", {})
        example = "example" in target.get("kind", [])
        if message.get("reason") == "compiler-artifact" and example and message.get("executable"):
            found[target["name"]] = Path(message["executable"])
    assert set(EXAMPLES) <= set(found), f"built {sorted(found)}"
    return found


@pytest.fixture
def processes() -> Iterator[list[subprocess.Popen[bytes]]]:
    """Processes a test starts; every one still running is killed by its PID at teardown."""
    started: list[subprocess.Popen[bytes]] = []
    yield started
    for process in started:
        if process.poll() is None:
            process.kill()
            process.wait(10)


def start_follower(
    examples: dict[str, Path],
    processes: list[subprocess.Popen[bytes]],
    service: ServeProcess,
    fleet: str,
    tmp_path: Path,
) -> tuple[subprocess.Popen[bytes], Path]:
    """Start ``follow_fleet --until-closed --json`` and wait until it follows the fleet."""
    out, err = tmp_path / "follow.out", tmp_path / "follow.err"
    with out.open("wb") as stdout, err.open("wb") as stderr:
        follower = subprocess.Popen(
            [
                str(examples["follow_fleet"]),
                *("-e", service.endpoint, "--fleet", fleet, "--seconds", "600"),
                *("--until-closed", "--json"),
            ],
            stdout=stdout,
            stderr=stderr,
        )
    processes.append(follower)
    wait_until(
        lambda: "following" in err.read_text() or follower.poll() is not None,
        30.0,
        "the Rust follower to subscribe",
    )
    assert follower.poll() is None, err.read_text()
    return follower, out


def follower_output(follower: subprocess.Popen[bytes], out: Path) -> list[dict[str, Any]]:
    """Wait for the follower to end by itself; return the messages it printed."""
    assert follower.wait(600) == 0, out.read_text()
    return [json.loads(line) for line in out.read_text().splitlines()]


def offline_segment(path: Path) -> list[dict[str, Any]]:
    """The transitions ``lessmap segment --method paper FILE`` prints (then a summary line)."""
    result = subprocess.run(
        [sys.executable, "-m", "lessmap", "segment", "--method", "paper", str(path)],
        capture_output=True,
        text=True,
        timeout=600,
        check=True,
    )
    records = [json.loads(line) for line in result.stdout.splitlines()]
    assert records[-1]["summary"] is True
    return records[:-1]


def test_rust_publisher_and_subscriber_reproduce_offline_segment(
    examples: dict[str, Path],
    processes: list[subprocess.Popen[bytes]],
    serve: Callable[..., ServeProcess],
    fleet_name: str,
    tmp_path: Path,
) -> None:
    path = dataset("dlr.frames.jsonl")
    expected = offline_segment(path)
    frames = sum(1 for line in path.read_text().splitlines() if line.strip())
    # max-batch-frames 1: decide at every frame, whatever the pace, as the offline run does;
    # the paper on both sides, whose every printed field is compared below.
    service = serve("--max-batch-frames", "1", "--method", "paper")
    follower, out = start_follower(examples, processes, service, fleet_name, tmp_path)

    replay = subprocess.run(
        [str(examples["replay_frames"]), str(path), "-e", service.endpoint, "--fleet", fleet_name],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert replay.returncode == 0, replay.stderr + service.log()[-4000:]
    assert json.loads(replay.stdout)["frames"] == frames

    messages = follower_output(follower, out)
    got = [m for m in messages if m["type"] == "Transition"]
    [state] = [m for m in messages if m["type"] == "SessionState"]
    assert len(got) == len(expected) > 100
    for offline, online in zip(expected, got, strict=True):
        # Every field `lessmap segment` prints is equal, floats bit for bit.
        assert online["robot"] == offline["robot"]
        for field in ("seq", "boundary_seq", "stamp_s", "reason", "ncut", "lambda2"):
            assert online[field] == offline[field], (field, offline["seq"])
        assert online["closed"] == offline["closed"]
        assert {k: online["opened"][k] for k in offline["opened"]} == offline["opened"]
        assert online["boundary_features"] == offline["boundary_features"]
        assert online["fleet"] == fleet_name
        assert online["instance"] == service.instance
        assert online["batch_frames"] == 1
        assert online["partition"] == partition_of(fleet_name, offline["robot"])
    assert state["open"] is False
    assert state["frames_applied"] == frames
    assert (state["frames_missing"], state["frames_rejected"], state["frames_duplicate"]) == (
        0,
        0,
        0,
    )
    assert state["transitions"] == len(expected)
    assert service.terminate() == 0


def test_rust_examples_walk_into_the_next_room(
    examples: dict[str, Path],
    processes: list[subprocess.Popen[bytes]],
    serve: Callable[..., ServeProcess],
    tmp_path: Path,
) -> None:
    service = serve("--max-batch-frames", "1")
    follower, out = start_follower(examples, processes, service, "example", tmp_path)
    walk = subprocess.run(
        [str(examples["publish_walk"]), "-e", service.endpoint],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert walk.returncode == 0, walk.stderr + service.log()[-4000:]
    assert walk.stdout.splitlines()[-1] == "frame 83: 12 features"

    messages = follower_output(follower, out)
    transitions = [m for m in messages if m["type"] == "Transition"]
    [state] = [m for m in messages if m["type"] == "SessionState"]
    assert [t["robot"] for t in transitions] == ["walker"]
    assert 40 <= transitions[0]["boundary_seq"] <= 44  # the door
    assert (state["frames_applied"], state["open"], state["transitions"]) == (84, False, 1)
    assert service.terminate() == 0


def run_close_fleet(examples: dict[str, Path], endpoint: str, *args: str) -> dict[str, Any]:
    """Run ``close_fleet`` to its end (bounded) and return its JSON summary."""
    result = subprocess.run(
        [str(examples["close_fleet"]), "-e", endpoint, *args],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    summary: dict[str, Any] = json.loads(result.stdout)
    return summary


def test_rust_close_all_ends_every_session_of_a_fleet(
    examples: dict[str, Path],
    serve: Callable[..., ServeProcess],
    fleet_name: str,
) -> None:
    service = serve()
    robots, frames = 8, 5
    summary = run_close_fleet(
        examples,
        service.endpoint,
        *("--fleet", fleet_name, "--robots", str(robots), "--frames", str(frames)),
        *("--timeout-ms", "5000"),
    )
    assert (summary["closed"], summary["unconfirmed"], summary["failures"]) == (robots, [], [])
    assert summary["close_s"] < summary["timeout_s"]
    sessions = summary["sessions"]
    assert sorted(sessions) == sorted(f"robot-{i}" for i in range(robots))

    with lessmap_client.connect(service.endpoint, timeout_s=20.0) as conn:
        # close_all returned once each end was confirmed: every frame is applied already
        # (the session closed, or open with its end put again and on its way).
        states = {s.robot: s for s in conn.states(fleet_name, timeout_s=5.0)}
        assert {r: (s.session, s.frames_applied) for r, s in states.items()} == {
            robot: (session, frames) for robot, session in sessions.items()
        }, service.log()[-4000:]

        def all_closed() -> bool:
            return all(not s.open for s in conn.states(fleet_name, timeout_s=2.0))

        wait_until(all_closed, 30.0, "every session closed", service.log)
        for state in conn.states(fleet_name, timeout_s=5.0):
            assert (state.frames_missing, state.frames_rejected) == (0, 0), state
    assert service.terminate() == 0


def test_rust_close_all_without_a_service_reports_every_end_at_once(
    examples: dict[str, Path],
    router: str,
    fleet_name: str,
) -> None:
    summary = run_close_fleet(
        examples,
        router,
        *("--fleet", fleet_name, "--robots", "4", "--frames", "3"),
        *("--timeout-ms", "5000", "--serve-wait-ms", "0"),
    )
    assert (summary["closed"], summary["failures"]) == (4, [])
    assert summary["close_s"] < summary["timeout_s"]
    assert summary["unconfirmed"] == [
        {
            "robot": f"robot-{i}",
            "session": summary["sessions"][f"robot-{i}"],
            "last_seq": 2,
            "reason": "no live lessmap instance",
        }
        for i in range(4)
    ]

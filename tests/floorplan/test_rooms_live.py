"""``lessmap rooms --fleet``: a running fleet's room map, from real processes on loopback.

A real ``lessmap serve``, the shipped example floor plan walked by two simulated robots and
replayed to the service, and ``lessmap rooms --fleet`` following them: its last map must be
the one ``lessmap rooms`` draws offline from the same frames segmented by the same method.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from lessmap.floorplan.example import EXAMPLE_LABELS, EXAMPLE_YAML
from lessmap.floorplan.mapfile import read_room_labels
from tests.conftest import wait_until

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from tests.conftest import ServeProcess


def lessmap(*argv: str | Path, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lessmap", *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )


@pytest.fixture(scope="module")
def walk(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two robots touring the example floor plan: the frames file (with poses)."""
    folder = tmp_path_factory.mktemp("walk")
    done = lessmap("sim", "--floorplan", EXAMPLE_YAML, "--out", folder, "--seed", "0", "-q")
    assert done.returncode == 0, done.stderr
    return folder / "example.frames.jsonl"


def same_partition(a: np.ndarray[Any, Any], b: np.ndarray[Any, Any]) -> bool:
    """The two maps label the same cells and group them alike (numbers aside)."""
    if not np.array_equal(a > 0, b > 0):
        return False
    pairs = set(zip(a[a > 0].tolist(), b[b > 0].tolist(), strict=True))
    return len(pairs) == len({x for x, _ in pairs}) == len({y for _, y in pairs})


@pytest.mark.timeout(300)  # an offline run, a service, a follower and a replay, one after another
def test_a_followed_fleet_gets_the_offline_room_map(
    walk: Path, serve: Callable[..., ServeProcess], tmp_path: Path
) -> None:
    offline_out = tmp_path / "offline"
    offline = lessmap(
        "rooms", walk, "--method", "areas", "--map", EXAMPLE_YAML, "--labels", EXAMPLE_LABELS,
        "-o", offline_out, "-q",
    )  # fmt: skip
    assert offline.returncode == 0, offline.stderr
    [expected] = [json.loads(line) for line in offline.stdout.splitlines()]
    frames = sum(1 for line in walk.read_text().splitlines() if line.strip())
    service = serve("--memory-only", "--max-batch-frames", "1", "--method", "areas")
    fleet = f"rooms-{uuid.uuid4().hex[:6]}"
    live_out, err_path = tmp_path / "live", tmp_path / "follow.err"
    with err_path.open("w") as err:
        follower = subprocess.Popen(
            [sys.executable, "-m", "lessmap", "-v", "rooms", "--fleet", fleet, "--map",
             str(EXAMPLE_YAML), "--labels", str(EXAMPLE_LABELS), "-o", str(live_out),
             "--every", "1", "-e", service.endpoint, "--connect-timeout", "30"],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )  # fmt: skip
    assert follower.stdout is not None
    records: list[dict[str, Any]] = []
    reader = threading.Thread(
        target=lambda: records.extend(json.loads(line) for line in follower.stdout or ()),
        daemon=True,
    )
    reader.start()

    def unique_transitions(counts: dict[str, int]) -> int:
        return counts["transitions"] - counts.get("transitions repeated", 0)

    def caught_up() -> bool:
        # a map drawn after every frame and every transition the offline run decided
        return any(
            r["counts"]["frames"] == frames
            and unique_transitions(r["counts"]) >= expected["transitions"]
            for r in list(records)
        )

    try:
        wait_until(
            lambda: "following fleet" in err_path.read_text(),
            60.0,
            "the follower's subscriptions",
            err_path.read_text,
        )
        time.sleep(1.0)  # the subscriptions reach the router
        replay = lessmap(
            "replay", walk, "--fleet", fleet, "-e", service.endpoint, "--speed", "20",
            "--settle", "2", "-q",
        )  # fmt: skip
        assert replay.returncode == 0, replay.stderr
        wait_until(caught_up, 120.0, "a map of every frame and transition", err_path.read_text)
        follower.send_signal(signal.SIGINT)
        follower.wait(timeout=60)
    finally:
        if follower.poll() is None:
            os.kill(follower.pid, signal.SIGKILL)
            follower.wait()
        reader.join(timeout=30)  # the pipe ends with the process
        follower.stdout.close()
    assert follower.returncode == 0, err_path.read_text()
    assert "Traceback" not in err_path.read_text()
    assert len(records) >= 2, "a map while the robots walked, and the last"
    assert [r["final"] for r in records] == [False] * (len(records) - 1) + [True]
    last = records[-1]
    assert last["counts"]["frames"] == frames
    assert last["poses"] == frames
    assert last["robots"] == ["robot0", "robot1"]
    assert records[0]["poses"] < frames  # drawn while they walked, not only at the end

    assert unique_transitions(last["counts"]) == expected["transitions"]
    assert last["rooms"] == expected["rooms"]
    assert last["benchmark"] == expected["benchmark"]
    live_map = read_room_labels(Path(last["files"]["pgm"]))
    assert same_partition(live_map, read_room_labels(offline_out.with_suffix(".pgm")))
    assert not list(tmp_path.glob(".*.part")), "no half-written file is left"


def test_a_fleet_without_frames_is_one_line(
    serve: Callable[..., ServeProcess], tmp_path: Path
) -> None:
    service = serve("--memory-only")
    done = lessmap(
        "rooms", "--fleet", "nobody", "--map", EXAMPLE_YAML, "-o", tmp_path / "m",
        "--duration", "1", "-e", service.endpoint, "--connect-timeout", "30",
    )  # fmt: skip
    assert done.returncode == 1
    [line] = done.stderr.strip().splitlines()
    assert "no frame with a pose of fleet nobody" in line
    assert not (tmp_path / "m.pgm").exists()


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        ((), "give FRAMES (a file) or --fleet F"),
        (("frames.jsonl", "--fleet", "f"), "give FRAMES (a file) or --fleet F"),
        (("--fleet", "f", "--transitions", "t.jsonl"), "no --transitions"),
        (("--fleet", "*"), "names one fleet"),
        (("--fleet", "f", "--method", "paper"), "no --method"),
        (("frames.jsonl", "--duration", "5"), "a file has no duration"),
    ],
)
def test_a_wrong_source_is_one_line(argv: tuple[str, ...], says: str, tmp_path: Path) -> None:
    done = lessmap("rooms", *argv, "--map", EXAMPLE_YAML, "-o", tmp_path / "m")
    assert done.returncode == 1
    [line] = done.stderr.strip().splitlines()
    assert says in line


@contextmanager
def robot_walked(endpoint: str, fleet: str, frames: int, x0_m: float) -> Iterator[None]:
    """Robot amr-1 of ``fleet``, after sending ``frames`` frames; connected inside the block.

    The frames go eastwards from ``x0_m`` along y = 6.75 m (the example plan's corridor);
    the robot's publication cache keeps them while the block runs.
    """
    from lessmap_client import connect

    with connect(endpoint, timeout_s=20.0) as conn:
        robot = conn.robot(fleet, "amr-1")
        assert robot.wait_for_service(20.0)
        for i in range(frames):
            robot.publish(range(i, i + 12), stamp_s=0.1 * i, pose=(x0_m + 0.1 * i, 6.75, 0.0))
        yield


def test_a_follower_started_late_fetches_the_robots_recent_frames(
    serve: Callable[..., ServeProcess], tmp_path: Path
) -> None:
    service = serve("--memory-only")
    fleet = f"late-{uuid.uuid4().hex[:6]}"
    with robot_walked(service.endpoint, fleet, frames=60, x0_m=1.0):
        late = lessmap(
            "rooms", "--fleet", fleet, "--map", EXAMPLE_YAML, "-o", tmp_path / "late",
            "--duration", "3", "-e", service.endpoint, "--connect-timeout", "30",
        )  # fmt: skip
        live_only = lessmap(
            "rooms", "--fleet", fleet, "--map", EXAMPLE_YAML, "-o", tmp_path / "live",
            "--duration", "3", "--history", "0", "-e", service.endpoint,
        )  # fmt: skip
    assert late.returncode == 0, late.stderr
    last = json.loads(late.stdout.splitlines()[-1])
    assert last["final"] is True
    assert (last["poses"], last["counts"]["frames"]) == (60, 60)
    # without history nothing was sent while it listened: one line, exit code 1
    assert live_only.returncode == 1
    assert "no frame with a pose of fleet" in live_only.stderr


def test_a_last_map_that_cannot_be_drawn_is_one_line(
    serve: Callable[..., ServeProcess], tmp_path: Path
) -> None:
    service = serve("--memory-only")
    fleet = f"off-{uuid.uuid4().hex[:6]}"
    with robot_walked(service.endpoint, fleet, frames=20, x0_m=1000.0):  # a km east of it
        off_map = lessmap(
            "rooms", "--fleet", fleet, "--map", EXAMPLE_YAML, "-o", tmp_path / "off",
            "--duration", "3", "-e", service.endpoint, "--connect-timeout", "30",
        )  # fmt: skip
        other_robot = lessmap(
            "rooms", "--fleet", fleet, "--robot", "amr-2", "--map", EXAMPLE_YAML,
            "-o", tmp_path / "other", "--duration", "3", "-e", service.endpoint,
        )  # fmt: skip
    for done, says in ((off_map, "no pose lies on a free cell"), (other_robot, "--robot")):
        assert done.returncode == 1, done.stderr
        [line] = done.stderr.strip().splitlines()
        assert says in line
        assert not done.stdout.strip()  # no map was written, none claimed


def test_a_signal_ends_the_follower_between_redraws(
    serve: Callable[..., ServeProcess], tmp_path: Path
) -> None:
    service = serve("--memory-only")
    err_path = tmp_path / "follow.err"
    with err_path.open("w") as err:
        follower = subprocess.Popen(
            [sys.executable, "-m", "lessmap", "-v", "rooms", "--fleet", "quiet", "--map",
             str(EXAMPLE_YAML), "-o", str(tmp_path / "m"), "--every", "600",
             "-e", service.endpoint, "--connect-timeout", "30"],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )  # fmt: skip
    try:
        wait_until(
            lambda: "following fleet" in err_path.read_text(),
            60.0,
            "the follower",
            err_path.read_text,
        )
        follower.send_signal(signal.SIGINT)
        follower.communicate(timeout=60)  # far below the 600 s until its next redraw
    finally:
        if follower.poll() is None:
            os.kill(follower.pid, signal.SIGKILL)
            follower.wait()
    assert follower.returncode == 1  # it saw no frame: said in one line
    assert "no frame with a pose of fleet quiet" in err_path.read_text()
    assert "Traceback" not in err_path.read_text()

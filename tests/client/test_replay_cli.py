"""``lessmap replay``: malformed files fail on one line before anything is published, and
the exit code and summary tell what the service applied (a real ``lessmap serve``)."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import TYPE_CHECKING, Any

import pytest

from lessmap_schemas.limits import DEFAULT_LIMITS
from tests.conftest import REPO, free_port

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from tests.conftest import ServeProcess

pytestmark = pytest.mark.timeout(180)


def run_replay(*args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lessmap", "replay", *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        cwd=REPO,
        check=False,
    )


def frame(robot: str = "a", seq: int = 0, **changes: Any) -> dict[str, Any]:
    row: dict[str, Any] = {
        "robot": robot,
        "seq": seq,
        "stamp": seq * 0.01,
        "features": [1, 2, 3],
        "pose": [0.0, 0.0, 0.0],
    }
    row.update(changes)
    return row


GOOD = json.dumps(frame(seq=0)).encode()

# (case, bad line 2 as bytes, what the one-line message says)
MALFORMED: list[tuple[str, bytes, str]] = [
    ("not-utf8", b'{"robot": "a\xff", "seq": 1}', "not UTF-8 (byte 0xff at column 13)"),
    ("invalid-json", b'{"robot": "a", "seq": 1', "not JSON ("),
    ("not-an-object", b"[1, 2, 3]", "expected an object, got list"),
    (
        "non-numeric-pose",
        json.dumps(frame(seq=1, pose=["x", 0, 0])).encode(),
        'pose must be [x, y, theta] (finite numbers) or null, got ["x", 0, 0]',
    ),
    (
        "missing-fields",
        json.dumps({"robot": "a", "stamp": 0.0}).encode(),
        "missing field 'seq', 'features'",
    ),
    (
        "seq-above-wire-limit",
        json.dumps(frame(seq=DEFAULT_LIMITS.max_seq + 1)).encode(),
        f"seq {DEFAULT_LIMITS.max_seq + 1} is above the wire limit {DEFAULT_LIMITS.max_seq}",
    ),
    (
        "too-many-features",
        json.dumps(
            frame(seq=1, features=list(range(DEFAULT_LIMITS.max_features_per_frame + 1)))
        ).encode(),
        f"{DEFAULT_LIMITS.max_features_per_frame + 1} features, more than the limit of "
        f"{DEFAULT_LIMITS.max_features_per_frame} per frame",
    ),
    (
        "negative-feature-id",
        json.dumps(frame(seq=1, features=[4, -1])).encode(),
        f"feature 1 must be an integer in 0..{DEFAULT_LIMITS.max_feature_id}, got -1",
    ),
    ("negative-seq", json.dumps(frame(seq=-1)).encode(), "seq must be an integer >= 0, got -1"),
    (
        "seq-not-increasing",
        json.dumps(frame(seq=0)).encode(),
        "seq 0 of robot 'a' is not above its previous seq 0",
    ),
    ("bad-robot-name", json.dumps(frame(robot="a/b", seq=0)).encode(), "robot"),
]


@pytest.mark.parametrize(
    ("line", "expected"), [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED]
)
def test_a_malformed_line_is_one_line_and_exit_1(
    tmp_path: Path, line: bytes, expected: str
) -> None:
    path = tmp_path / "bad.frames.jsonl"
    # A valid first line and a valid last line: the bad one in between must stop everything
    # before a single frame is published (no service here: publishing would need a router).
    path.write_bytes(GOOD + b"\n" + line + b"\n" + json.dumps(frame(seq=5)).encode() + b"\n")
    # An endpoint nobody listens on: if the file passed, connecting would fail differently.
    done = run_replay(str(path), "--fast", "-e", f"tcp/127.0.0.1:{free_port()}", timeout_s=60)
    assert done.returncode == 1
    assert done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"lessmap replay: {path}:2: "), lines[0]
    assert expected in lines[0]
    assert "Traceback" not in done.stderr


def write_frames(path: Path, rows: list[dict[str, Any]]) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    return path


def walk_rows(robots: tuple[str, ...], seqs: list[int]) -> list[dict[str, Any]]:
    rows = []
    for seq in seqs:
        for robot in robots:
            room = seq // 20
            features = [room * 10 + i for i in range(10) if (i + seq) % 4]
            rows.append(frame(robot, seq, features=features))
    return rows


def test_replay_through_a_service_reports_applied_equals_offered(
    serve: Callable[..., ServeProcess], fleet_name: str, tmp_path: Path
) -> None:
    path = write_frames(tmp_path / "ok.frames.jsonl", walk_rows(("a", "b"), list(range(60))))
    service = serve("--max-batch-frames", "1")
    done = run_replay(
        str(path),
        "--fleet",
        fleet_name,
        "--fast",
        "--connect-timeout",
        "20",
        "-e",
        service.endpoint,
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["ok"] is True
    # One decision per frame (--max-batch-frames 1): nothing was coalesced, and it says so.
    transitions = sum(r["transitions"] for r in summary["per_robot"].values())
    assert transitions > 0
    assert summary["coalesced"] == {"transitions": 0, "of": transitions, "largest_batch_frames": 1}
    assert "batches of frames" not in done.stderr
    assert (summary["frames"], summary["robots"], summary["applied"]) == (120, 2, 120)
    for name in ("a", "b"):
        robot = summary["per_robot"][name]
        assert (robot["offered"], robot["applied"], robot["missing"], robot["rejected"]) == (
            60,
            60,
            0,
            0,
        )
        assert robot["errors"] == {}


def test_replay_exits_1_naming_the_robot_with_missing_frames(
    serve: Callable[..., ServeProcess], fleet_name: str, tmp_path: Path
) -> None:
    rows = walk_rows(("whole",), list(range(30))) + walk_rows(
        ("gappy",), [*range(10), *range(20, 30)]
    )
    rows.sort(key=lambda r: r["seq"])
    path = write_frames(tmp_path / "gap.frames.jsonl", rows)
    service = serve("--max-batch-frames", "1")
    done = run_replay(
        str(path),
        "--fleet",
        fleet_name,
        "--fast",
        "--connect-timeout",
        "20",
        "--progress",
        "0.2",
        "-e",
        service.endpoint,
    )
    assert done.returncode == 1, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["ok"] is False
    gappy, whole = summary["per_robot"]["gappy"], summary["per_robot"]["whole"]
    assert (gappy["offered"], gappy["applied"], gappy["missing"]) == (20, 20, 10)
    assert gappy["errors"].get("SEQ_GAP", 0) >= 1
    assert (whole["offered"], whole["applied"], whole["missing"]) == (30, 30, 0)
    verdict = [line for line in done.stderr.splitlines() if "did not apply" in line]
    assert len(verdict) == 1, done.stderr
    assert "gappy (10 missing)" in verdict[0]
    assert "whole" not in verdict[0]


def test_replay_without_a_service_exits_1(fleet_name: str, tmp_path: Path) -> None:
    # A router and no service: nothing acknowledges the frames, so the replay cannot succeed.
    port = free_port()
    router = subprocess.Popen(
        [sys.executable, "-c", _ROUTER, f"tcp/127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        path = write_frames(tmp_path / "x.frames.jsonl", walk_rows(("a",), list(range(5))))
        done = run_replay(
            str(path),
            "--fleet",
            fleet_name,
            "--fast",
            "--wait-service",
            "0.5",
            "--settle",
            "1",
            "-e",
            f"tcp/127.0.0.1:{port}",
        )
    finally:
        router.terminate()
        router.wait(10)
    assert done.returncode == 1, done.stderr
    # The old spelling of --connect-timeout still works, and says which one to use.
    assert "lessmap replay: --wait-service is deprecated; use --connect-timeout" in done.stderr
    assert "no lessmap service answered" in done.stderr
    assert "a (no final state from the service)" in done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["per_robot"]["a"]["offered"] == 5
    assert summary["per_robot"]["a"]["applied"] is None


_ROUTER = """
import sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"router"')
conf.insert_json5("listen/endpoints", '["%s"]' % sys.argv[1])
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf):
    time.sleep(120)
"""

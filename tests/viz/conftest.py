"""A fleet walking through rooms with poses, and the lessmap view/record processes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from typing import TYPE_CHECKING, Any

import pytest

pytest.importorskip("foxglove", reason="the [viz] extra is not installed")

if TYPE_CHECKING:
    from pathlib import Path

    from lessmap_client.connection import Connection

FRAMES_PER_ROOM = 15
ROOMS = 2


def walk(room_offset: float = 0.0) -> list[tuple[list[int], tuple[float, float, float]]]:
    """Frames of a robot crossing ``ROOMS`` rooms of 8 features each, with poses along x."""
    frames = []
    for room in range(ROOMS):
        tags = [100 * room + i for i in range(1, 9)]
        for k in range(FRAMES_PER_ROOM):
            seen = [tags[(k + j) % 8] for j in range(5)]
            x = 10.0 * room + 0.5 * k
            frames.append((seen, (x, room_offset, 0.0)))
    return frames


def publish_walks(conn: Connection, fleet: str, robots: list[str]) -> None:
    """Publish every robot's walk (robots interleaved) and end their sessions."""
    publishers = [conn.robot(fleet, robot) for robot in robots]
    for publisher in publishers:
        assert publisher.wait_for_service(20)
    walks = [walk(2.0 * i) for i in range(len(robots))]
    for step in range(len(walks[0])):
        for publisher, frames in zip(publishers, walks, strict=True):
            features, pose = frames[step]
            publisher.publish(features, stamp_s=100.0 + step, pose=pose)
    # Sessions stay open: the viewer's state table shows them as they are.


def start_command(tmp_path: Path, name: str, *argv: str) -> subprocess.Popen[str]:
    with (tmp_path / f"{name}.log").open("w") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "lessmap", "-v", *argv],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
            env=dict(os.environ),
        )


def stop_command(process: subprocess.Popen[str]) -> dict[str, Any]:
    process.send_signal(signal.SIGTERM)
    try:
        out, _ = process.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(5)
        raise
    assert process.returncode == 0
    summary: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return summary

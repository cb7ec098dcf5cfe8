"""The viewer role end to end: ``lessmap view`` as ``viewer.F`` draws poses, as ``app.F`` not.

Both views follow the same run through the site's router (mTLS, access control), so the app's
empty trajectories are a refusal, not a broken path: the viewer's frames crossed it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from tests.conftest import wait_until
from tests.viz.conftest import start_command, stop_command

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from lessmap_client import Connection
    from tests.conftest import ServeProcess
    from tests.security.conftest import SecureSite

pytest.importorskip("foxglove", reason="the [viz] extra is not installed")
pytestmark = pytest.mark.timeout(120)

FRAMES = 40


def logged(log: Path, text: str) -> Callable[[], bool]:
    return lambda: text in log.read_text()


def test_a_viewer_reads_the_robots_poses_and_an_app_does_not(
    site: SecureSite,
    service: ServeProcess,
    connect_as: Callable[..., Connection],
    tmp_path: Path,
) -> None:
    views = {
        role: start_command(
            tmp_path,
            role,
            *("view", "--fleet", site.fleet, "--port", "0"),
            *("--zenoh-config", site.config(role)),
        )
        for role in ("viewer", "app")
    }
    summaries = {}
    try:
        for role in views:
            wait_until(logged(tmp_path / f"{role}.log", "following fleet"), 30, f"{role}'s view")
        robot = connect_as("robot").robot(site.fleet, "amr-1")
        assert robot.wait_for_service(20.0), service.log()
        for i in range(FRAMES):  # one room, then a disjoint one: one transition
            base = 0 if i < FRAMES // 2 else 1000
            robot.publish(range(base, base + 12), stamp_s=0.1 * i, pose=(0.5 * i, 0.0, 0.0))
        wait_until(
            lambda: "no frame reached the view" in (tmp_path / "app.log").read_text(),
            30,
            "the app's view to say it reads no frame",
        )
        wait_until(
            lambda: "submap 0 -> 1" in (tmp_path / "viewer.log").read_text(),
            30,
            "the viewer's view to get the transition",
        )
    finally:
        for role, view in views.items():
            summaries[role] = stop_command(view)

    assert summaries["viewer"]["frames"] == FRAMES
    assert summaries["viewer"]["transitions"] == 1
    assert summaries["viewer"]["scene updates"] >= 1
    assert "no frames readable" not in summaries["viewer"]
    assert "frames" not in summaries["app"]
    assert summaries["app"]["transitions"] == 1
    assert summaries["app"]["no frames readable"] == 1

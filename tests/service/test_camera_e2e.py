"""A camera robot (1,000 features a frame) against a real ``lessmap serve`` on loopback.

Under the default method the frames are sampled to ``max_features_kept`` before the core, so
the default budgets take them; the paper keeps every feature, and its pairs budget refuses
them. Nothing here asserts on speed (figures: ``benchmarks/camera.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from lessmap.cli.segment import segment_areas
from lessmap.config.partitioning import PartitionSettings, area_params
from lessmap.files.frames import FrameRow
from lessmap_client import FleetClient, RobotPublisher
from tests.conftest import wait_until
from tests.service.test_budgets_e2e import Errors, stream
from tests.service.test_serve_e2e import drain, wait_closed

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

    from lessmap.core.areas.tracker import AreaTransition
    from tests.conftest import ServeProcess

pytestmark = pytest.mark.timeout(300)

FEATURES = 1000
RATE_HZ = 20.0


def camera_frames(count: int = 60) -> list[FrameRow]:
    """Two rooms of wall texture, 1,000 features a frame sliding along each room's 3,000."""
    frames = []
    for seq in range(count):
        base = 0 if seq < count // 2 else 100_000
        start = base + (seq % (count // 2)) * 60
        features = tuple(range(start, start + FEATURES))
        frames.append(FrameRow("cam", seq, seq / RATE_HZ, features, None))
    return frames


def test_a_camera_robot_is_served_by_default_and_refused_by_the_paper(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = camera_frames()
    service = serve()  # default settings: the areas method, default budgets
    session = client_session(service.endpoint)
    errors = Errors(session, fleet_name)
    with FleetClient(fleet_name, "cam", session=session) as client:
        with RobotPublisher(fleet_name, "cam", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            stream(robot, frames, RATE_HZ)
        state = wait_closed(client, fleet_name, "cam", len(frames))
    assert (state.method, state.frames_rejected) == ("areas", 0)
    assert state.transitions >= 1  # at least the door between the two rooms
    assert state.nodes <= 2 * 256  # the CovGraph holds sampled features only
    assert errors.of("cam") == []

    paper = serve("--method", "paper", "--memory-only")  # the first holds the state folder
    session = client_session(paper.endpoint)
    refused = Errors(session, fleet_name)
    with RobotPublisher(fleet_name, "cam", session=session) as robot:
        assert robot.wait_for_service(20.0), paper.log()
        stream(robot, frames[:2], RATE_HZ)
        wait_until(lambda: len(refused.of("cam")) >= 2, 30.0, "the paper to refuse two frames")
    assert all("max_pairs_per_frame" in e.detail for e in refused.of("cam"))
    errors.close()
    refused.close()


def test_a_camera_robot_live_equals_lessmap_segment(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = camera_frames()
    expected: list[AreaTransition] = []
    segment_areas(frames, area_params(PartitionSettings()), lambda _r, c: expected.append(c))
    # Decide at every frame whatever the pace, as the offline run does.
    service = serve("--max-batch-frames", "1")
    session = client_session(service.endpoint)
    with FleetClient(fleet_name, "cam", session=session) as client:
        with RobotPublisher(fleet_name, "cam", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            stream(robot, frames, RATE_HZ)
        wait_closed(client, fleet_name, "cam", len(frames))
        got = drain(client)
    assert expected
    assert [(t.boundary_seq, t.area, t.closed.features, t.opened.features) for t in got] == [
        (
            c.transition.boundary_seq,
            c.area,
            list(c.transition.closed.features),
            list(c.transition.opened.features),
        )
        for c in expected
    ]
    assert len(got[0].closed.features) < FEATURES  # sampled, the same ids as offline

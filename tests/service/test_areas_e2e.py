"""``lessmap serve --method areas`` end to end: a robot walks a simulated building, the fleet
app sees its revisits named, and the ``areas`` query answers the area graph."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from lessmap.core import PartitionParams
from lessmap.core.segmenter import Method, make_segmenter
from lessmap.runtime.sessions import wire_area_graph
from lessmap.sim.simulator import simulate
from lessmap_client import FleetClient, RobotPublisher
from tests.service.test_serve_e2e import drain, start_service, wait_closed

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

    from tests.conftest import ServeProcess

pytestmark = pytest.mark.timeout(240)


def walk() -> list[tuple[int, float, list[int]]]:
    run = simulate(0, rooms=4, robots=1, frames_per_robot=300)
    return [(f["seq"], f["stamp"], list(f["features"])) for f in run.frames]


@pytest.mark.parametrize("method", list(Method))
def test_served_changes_and_area_graph_equal_the_segmenter_offline(
    method: Method,
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    frames = walk()
    offline = make_segmenter(method, PartitionParams.from_profile("laser"))
    expected = []
    for seq, stamp, features in frames:
        offline.apply(seq, stamp, features)
        expected += [
            (c.transition.seq, c.reason, c.area, c.left_area, c.revisit_of is not None)
            for c in offline.decide()
        ]
    service = start_service(serve, "--method", method.value)
    session = client_session(service.endpoint)
    with FleetClient(fleet_name, session=session) as client:
        with RobotPublisher(fleet_name, "amr", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            for seq, stamp, features in frames:
                robot.publish(features, stamp_s=stamp, seq=seq)
        state = wait_closed(client, fleet_name, "amr", len(frames))
        got = drain(client)
        graph = client.area_graph("amr")
    assert [(t.seq, t.reason, t.area, t.left_area, t.revisit) for t in got] == expected
    assert (state.method, state.current_area) == (method.value, offline.current_area)
    if method is Method.AREAS:
        assert any(t.revisit for t in got)  # the walk comes back to a room
    assert graph is not None
    want = wire_area_graph(
        fleet_name,
        "amr",
        state.session,
        offline.area_graph(),
        method=method.value,
        instance=service.instance,
        epoch=graph.epoch,
    )
    assert graph == want
    assert service.terminate() == 0

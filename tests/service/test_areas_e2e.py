"""``lessmap serve`` end to end, each method and the default (areas): a robot walks a
simulated building, the fleet app sees its revisits named, and the ``areas`` query answers the
area graph."""

from __future__ import annotations

import subprocess
import sys
from typing import TYPE_CHECKING

import pytest

from lessmap.core import PartitionParams
from lessmap.core.areas.tracker import AreaParams
from lessmap.core.segmenter import Method, make_segmenter
from lessmap.files.frames import read_frames
from lessmap.runtime.sessions import wire_area_graph
from lessmap.sim.simulator import simulate
from lessmap_client import FleetClient, RobotPublisher
from tests.conftest import dataset
from tests.service.test_serve_e2e import drain, start_service, wait_closed

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

    from tests.conftest import ServeProcess

pytestmark = pytest.mark.timeout(240)


def walk() -> list[tuple[int, float, list[int]]]:
    run = simulate(0, rooms=4, robots=1, frames_per_robot=300)
    return [(f["seq"], f["stamp"], list(f["features"])) for f in run.frames]


@pytest.mark.parametrize("chosen", [*Method, None], ids=[*Method, "default"])
def test_served_changes_and_area_graph_equal_the_segmenter_offline(
    chosen: Method | None,
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    # None: `serve` without --method, whose sessions run areas (the default since issue 18).
    method = Method.AREAS if chosen is None else chosen
    frames = walk()
    offline = make_segmenter(method, PartitionParams.from_profile("laser"))
    expected = []
    for seq, stamp, features in frames:
        offline.apply(seq, stamp, features)
        expected += [
            (c.transition.seq, c.reason, c.area, c.left_area, c.revisit_of is not None)
            for c in offline.decide()
        ]
    service = start_service(serve, method=None if chosen is None else chosen.value)
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
    assert (state.method, state.current_area) == (method.wire, offline.current_area)
    if method is Method.AREAS:
        assert any(t.revisit for t in got)  # the walk comes back to a room
    assert graph is not None
    want = wire_area_graph(
        fleet_name,
        "amr",
        state.session,
        offline.area_graph(),
        method=method.wire,
        instance=service.instance,
        epoch=graph.epoch,
    )
    assert graph == want
    assert service.terminate() == 0


def test_a_fleet_declared_to_omit_empty_frames_has_its_stamp_gaps_read(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    # MRCLAM's robot 3 sends a frame only when it sees a landmark; turning between the
    # arena's two walls it sees nothing for seconds, which only its stamps show. The same
    # frames go to two fleets: the one declared to leave out its empty frames keeps the
    # robot in one area, the other (stamps not read: a gap could be a stall) does not.
    rows = [r for r in read_frames(dataset("mrclam6.frames.jsonl")) if r.robot == "3"]
    frames = [(r.seq, r.stamp_s, list(r.features)) for r in rows]
    declared, other = fleet_name, f"{fleet_name}-x"
    expected: dict[str, list[tuple[int, str, int]]] = {}
    for fleet, omitted in ((declared, True), (other, False)):
        areas = AreaParams().for_stream(empty_frames_omitted=omitted)
        offline = make_segmenter(Method.AREAS, area_params=areas)
        expected[fleet] = []
        for seq, stamp, features in frames:
            offline.apply(seq, stamp, features)
            expected[fleet] += [(c.transition.seq, c.reason, c.area) for c in offline.decide()]
    assert expected[declared] == []
    assert len(expected[other]) >= 3
    service = start_service(serve, "--method", "areas", "--empty-frames-omitted", declared)
    session = client_session(service.endpoint)
    for fleet in (declared, other):
        with FleetClient(fleet, session=session) as client:
            with RobotPublisher(fleet, "r3", session=session) as robot:
                assert robot.wait_for_service(20.0), service.log()
                for seq, stamp, features in frames:
                    robot.publish(features, stamp_s=stamp, seq=seq)
            wait_closed(client, fleet, "r3", len(frames))
            got = drain(client)
        assert [(t.seq, t.reason, t.area) for t in got] == expected[fleet], fleet
    assert service.terminate() == 0


def test_a_bad_fleet_name_for_empty_frames_omitted_is_one_line() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "lessmap", "serve", "--empty-frames-omitted", "a/b"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "empty_frames_omitted" in lines[0]
    assert "Traceback" not in result.stderr

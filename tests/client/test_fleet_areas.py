"""Fleet areas: the SDK's merge of the robots' area graphs, offline and over the bus.

The merge rules themselves are pinned in tests/core/test_area_graph.py (on the core's
graphs); here: the wire's ``AreaGraph`` merges the same way, and a fleet spread over two
real ``lessmap serve --method areas`` instances answers ``FleetClient.fleet_area_graph``
and ``lessmap areas`` with the graph the segmenter gives offline.
"""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.core import PartitionParams
from lessmap.core.segmenter import Method, make_segmenter
from lessmap.files.area_graph import read_graph_file
from lessmap.runtime.sessions import wire_area_graph
from lessmap.sim.simulator import simulate
from lessmap_client import FleetClient, RobotPublisher
from lessmap_client.fleet_areas import FleetParams, fleet_graph, fleet_graph_of
from lessmap_client.testing import FakeBus
from lessmap_schemas import partition
from lessmap_schemas.codec import decode
from lessmap_schemas.messages import AreaGraph, AreaNode, Passage
from tests.conftest import wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

    from tests.conftest import ServeProcess

FLEET = "site"


def wire(robot: str, *areas: tuple[int, range], fleet: str = FLEET) -> AreaGraph:
    """A robot's graph as the service sends it: areas in a chain, one passage each."""
    return AreaGraph(
        fleet=fleet,
        robot=robot,
        session="s1",
        instance="i1",
        epoch=1,
        method="areas",
        areas=[
            AreaNode(
                id=i, frames=10, visits=1, first_seq=10 * i, last_seq=10 * i + 9, features=list(f)
            )
            for i, f in areas
        ],
        passages=[
            Passage(a=i, b=j, a_to_b=1, b_to_a=0, boundary_features=[[f[0], 1]])
            for (i, _), (j, f) in itertools.pairwise(areas)
        ],
    )


ROOM_A, ROOM_B = range(20), range(100, 120)


def test_wire_graphs_of_robots_in_one_room_share_a_fleet_area() -> None:
    graphs = [wire("r1", (0, ROOM_A), (1, ROOM_B)), wire("r2", (0, ROOM_B[2:]))]
    fleet = fleet_graph_of(graphs, FleetParams(shared_features=True))
    assert [n.members for n in fleet.nodes] == [(("r1", 0),), (("r1", 1), ("r2", 0))]
    assert fleet.area_of["r2", 0] == fleet.area_of["r1", 1] == 1
    assert fleet.robots_in(1) == ("r1", "r2")
    assert fleet.key_of("r2", 0) == ("r1", 1)
    # A robot that comes first in name order renumbers the fleet ids, not the keys.
    more = fleet_graph_of(
        [*graphs, wire("a0", (0, range(500, 520)))], FleetParams(shared_features=True)
    )
    assert more.area_of["r2", 0] != fleet.area_of["r2", 0]
    assert more.key_of("r2", 0) == ("r1", 1)
    assert [(e.a, e.b, e.a_to_b, e.robots) for e in fleet.edges] == [(0, 1, 1, ("r1",))]
    alone = fleet_graph_of(graphs)  # ids are per robot: no merge without shared features
    assert len(alone.nodes) == 3


def test_a_merge_takes_one_fleet_and_one_graph_per_robot() -> None:
    with pytest.raises(ValueError, match="several fleets"):
        fleet_graph_of([wire("r1", (0, ROOM_A)), wire("r2", (0, ROOM_A), fleet="other")])
    with pytest.raises(ValueError, match="two area graphs for robot 'r1'"):
        fleet_graph_of([wire("r1", (0, ROOM_A)), wire("r1", (0, ROOM_B))])


def test_fake_bus_answers_the_fleet_area_graph() -> None:
    bus = FakeBus()
    bus.set_area_graph(wire("r1", (0, ROOM_A), (1, ROOM_B)))
    bus.set_area_graph(wire("r2", (0, ROOM_A[1:])))
    with FleetClient(FLEET, session=bus.connect()) as client:
        fleet = client.fleet_area_graph(shared_features=True)
    assert [n.members for n in fleet.nodes] == [(("r1", 0), ("r2", 0)), (("r1", 1),)]


VECTORS = Path(__file__).resolve().parents[2] / "schemas" / "vectors" / "fleet_areas.json"


@pytest.mark.parametrize(
    "case",
    json.loads(VECTORS.read_text(encoding="utf-8"))["cases"],
    ids=lambda case: case["name"],
)
def test_fleet_area_vector(case: dict[str, Any]) -> None:
    # The same file the Rust client checks (clients/rust/tests/vectors.rs): one merge.
    graphs = [decode(bytes.fromhex(h), AreaGraph) for h in case["graphs_hex"]]
    fleet = fleet_graph_of(graphs, FleetParams(**case["params"]))
    want = case["fleet"]
    assert fleet.to_json() == {"nodes": want["nodes"], "edges": want["edges"]}
    assert [[r, a, f] for (r, a), f in sorted(fleet.area_of.items())] == want["area_of"]


def test_fleet_area_vectors_cover_each_rule() -> None:
    cases = {c["name"]: c for c in json.loads(VECTORS.read_text(encoding="utf-8"))["cases"]}
    shared = cases["robots in one room share a fleet area"]["fleet"]["nodes"]
    assert any(len({m[0] for m in n["members"]}) > 1 for n in shared)
    apart = cases["ids are per robot without shared features"]["fleet"]["nodes"]
    assert all(len(n["members"]) == 1 for n in apart)
    trimmed = cases["boundary features trimmed to the most frequent over robots"]
    assert all(len(e["boundary_features"]) == 4 for e in trimmed["fleet"]["edges"])


def robot_names(instances: list[str]) -> list[str]:
    """Two robot names whose partitions the two instances own one each."""
    owners: dict[str, str] = {}
    for k in range(1000):
        name = f"amr{k}"
        owner, _ = partition.owner_and_standby(partition.partition_of(FLEET, name), instances)
        assert owner is not None
        owners.setdefault(owner, name)
        if len(owners) == len(instances):
            return [owners[i] for i in instances]
    msg = "no robot names split over the instances"
    raise AssertionError(msg)


@pytest.mark.timeout(300)
def test_a_fleet_over_two_instances_merges_as_the_segmenter_offline(
    router: str,
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    tmp_path: Path,
) -> None:
    run = simulate(3, rooms=4, robots=2, frames_per_robot=300)  # one building: global ids
    joined = ("-m", "client", "-e", router, "--max-batch-frames", "1", "--method", "areas")
    services = [serve(*joined, "--state-dir", str(tmp_path / f"state-{k}")) for k in range(2)]
    names = robot_names([s.instance for s in services])
    streams = {
        name: [f for f in run.frames if f["robot"] == sim]
        for name, sim in zip(names, ("robot0", "robot1"), strict=True)
    }
    session = client_session(router)
    with FleetClient(FLEET, session=session) as client:

        def settled() -> bool:
            # Both alive and each serving the partitions it owns: the robots then publish to
            # their final owners (hand-overs mid-stream are the failover tests' subject).
            owned: dict[str, set[int]] = {s.instance: set() for s in services}
            for p, (owner, _) in client.coverage().items():
                if owner in owned:
                    owned[owner].add(p)
            serving = {h.instance: set(h.partitions) for h in client.health()}
            return all(owned[i] and serving.get(i) == owned[i] for i in owned)

        wait_until(
            settled,
            60.0,
            "two instances serving their partitions",
            lambda: services[0].log() + services[1].log(),
        )
        for name, frames in streams.items():
            with RobotPublisher(FLEET, name, session=session) as robot:
                assert robot.wait_for_service(20.0)
                for f in frames:
                    robot.publish(list(f["features"]), stamp_s=f["stamp"], seq=f["seq"])

        def all_closed() -> bool:
            states = client.states()
            return len(states) == 2 and all(
                not s.open and s.frames_applied == len(streams[s.robot]) for s in states
            )

        wait_until(all_closed, 120.0, "both sessions closed with every frame applied")
        current = {s.robot: s.current_area for s in client.states()}
        replies = client.area_graphs()
        fleet = client.fleet_area_graph(shared_features=True)
    assert {g.instance for g in replies} == {s.instance for s in services}  # one fleet, two hosts
    offline = {}
    for name, frames in streams.items():
        segmenter = make_segmenter(Method.AREAS, PartitionParams.from_profile("laser"))
        for f in frames:
            segmenter.apply(f["seq"], f["stamp"], list(f["features"]))
            segmenter.decide()
        offline[name] = segmenter.area_graph()
    for reply in replies:
        expected = wire_area_graph(
            FLEET,
            reply.robot,
            reply.session,
            offline[reply.robot],
            method="areas",
            instance=reply.instance,
            epoch=reply.epoch,
        )
        assert reply == expected, services[0].log() + services[1].log()
    params = FleetParams(shared_features=True)
    assert fleet == fleet_graph(offline, params)
    # The two robots walked the same rooms: some fleet areas hold areas of both.
    assert any(len(fleet.robots_in(n.area)) == 2 for n in fleet.nodes)

    # The command line: the same graph, as the file `lessmap plot --area-graph` draws.
    out = tmp_path / "fleet.json"
    argv = [sys.executable, "-m", "lessmap", "areas", "--fleet", FLEET, "--shared-features"]
    done = subprocess.run(
        [*argv, "-e", router, "--out", str(out)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert f"{len(fleet.nodes)} fleet areas" in done.stdout
    _, from_file = read_graph_file(out)
    assert from_file.nodes == fleet.nodes
    assert from_file.edges == fleet.edges
    printed = subprocess.run(
        [*argv, "-e", router, "--json"], capture_output=True, text=True, timeout=60
    )
    assert json.loads(printed.stdout)["fleet"] == json.loads(out.read_text())["fleet"]
    figure = tmp_path / "fleet.png"
    plotted = subprocess.run(
        [sys.executable, "-m", "lessmap", "plot", "--area-graph", str(out), "--out", str(figure)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert plotted.returncode == 0, plotted.stderr
    assert figure.stat().st_size > 0

    # The live view names each robot's place: its current area's fleet area.
    watch = ["watch", "--fleet", FLEET, "--shared-features", "--duration", "2", "-e", router]
    watched = subprocess.run(
        [sys.executable, "-m", "lessmap", *watch], capture_output=True, text=True, timeout=60
    )
    assert watched.returncode == 0, watched.stderr
    lines = watched.stdout.strip().splitlines()  # transitions as they come, then the table
    at = next(i for i, line in enumerate(lines) if line.startswith("robot "))
    header, rows = lines[at], lines[at + 2 :]
    assert header.split()[-1] == "place"
    assert len(rows) == 2
    for line in rows:
        name = line.split()[0].split("/")[1]
        first_robot, first_area = fleet.key_of(name, current[name])
        assert line.removesuffix("(closed)").split()[-1] == f"{first_robot}:{first_area}"


def test_areas_command_without_robots_is_one_line(router: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "lessmap", "areas", "--fleet", "nobody", "-e", router],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        f"lessmap areas: no robot of fleet 'nobody' answered at {router} within 2 s"
    ]


def test_watch_places_need_one_fleet() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "lessmap", "watch", "--shared-features"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1
    assert done.stderr.strip() == "lessmap watch: --shared-features follows one fleet: give --fleet"

"""Vectors of what every client computes beside the messages: partitions and the fleet merge.

Written by `generate.py` (`partition.json`, `fleet_areas.json`), like the message vectors.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:  # run from a checkout without installing the package
    sys.path.insert(0, str(HERE.parent))

from lessmap_schemas import MESSAGE_TYPES, encode  # noqa: E402
from lessmap_schemas.partition import PARTITIONS, partition_of, ranking, score  # noqa: E402


def partition_vectors() -> dict[str, object]:
    """Vectors of the partition function and of the rendezvous ranking (`partition.py`)."""
    robots = [
        ("warehouse", "amr-7"),
        ("warehouse", "amr-8"),
        ("test", "r0"),
        ("test", "r1"),
        ("a", "b"),
        ("_", "0"),
        ("fleet.x-1", "robot_" + "z" * 57),
    ] + [("mrclam6", f"r{i}") for i in range(1, 6)]
    instances = ["lessmap-a1", "lessmap-b2", "node-c", "host-1234", "x"]
    return {
        "type": "partition",
        "partitions": PARTITIONS,
        "robots": [
            {"fleet": fleet, "robot": robot, "partition": partition_of(fleet, robot)}
            for fleet, robot in robots
        ],
        "scores": [
            {"instance": name, "partition": p, "score_hex": f"{score(name, p):016x}"}
            for name in instances[:2]
            for p in (0, 1, PARTITIONS - 1)
        ],
        "rankings": [
            {"partition": p, "instances": live, "ranking": ranking(p, live)}
            for p in (0, 1, 2, 29, PARTITIONS - 1)
            for live in (instances, instances[:2], instances[:1], [])
        ],
    }


def fleet_area_vectors() -> dict[str, object]:
    """Vectors of the fleet merge (`lessmap_client.fleet_areas`): graphs in, fleet graph out.

    Not a message: the merge of robots' `AreaGraph` replies that every client runs the same
    way, so that a Python app and a Rust app name the same places. Each case holds the robots'
    graphs as `AreaGraph` payloads (in the order a client may receive them), the merge
    parameters, and the fleet graph the reference merge gives.
    """
    clients = HERE.parent.parent / "clients" / "python"
    if str(clients) not in sys.path:
        sys.path.insert(0, str(clients))
    from lessmap_client.fleet_areas import FleetParams, fleet_graph_of

    def graph(robot: str, areas: list[range], passages: list[tuple[int, int, int, int]]) -> Any:
        return MESSAGE_TYPES["AreaGraph"](
            fleet="site",
            robot=robot,
            session="s1",
            instance="i1",
            epoch=1,
            method="areas",
            areas=[
                {
                    "id": i,
                    "frames": 10 + i,
                    "visits": 1 + i % 2,
                    "first_seq": 10 * i,
                    "last_seq": 10 * i + 9,
                    "features": list(f),
                }
                for i, f in enumerate(areas)
            ],
            passages=[
                {
                    "a": a,
                    "b": b,
                    "a_to_b": ab,
                    "b_to_a": ba,
                    "boundary_features": [
                        [1000 * a + b + k, 3 - k % 3] for k in range(ab + ba + 1)
                    ],
                }
                for a, b, ab, ba in passages
            ],
        )

    room_a, room_b, room_c = range(20), range(100, 120), range(200, 220)
    room_p, room_q = range(10), range(20, 32)
    rooms = {
        "r1": graph("r1", [room_a, room_b], [(0, 1, 1, 0)]),
        "r2": graph("r2", [room_b[:15], room_c], [(0, 1, 2, 1)]),
        "r3": graph("r3", [range(200, 222), room_a[:3]], [(0, 1, 1, 1)]),
    }
    cases: list[tuple[str, list[Any], dict[str, Any]]] = [
        ("ids are per robot without shared features", list(rooms.values()), {}),
        ("robots in one room share a fleet area", list(rooms.values()), {"shared_features": True}),
        (
            "the same, robots received in another order",
            [rooms["r3"], rooms["r1"], rooms["r2"]],
            {"shared_features": True},
        ),
        (
            "containment below the threshold keeps areas apart",
            [graph("r1", [range(10)], []), graph("r2", [range(2, 12)], [])],
            {"shared_features": True, "min_containment": 0.81},
        ),
        (
            "containment at the threshold links",
            [graph("r1", [range(10)], []), graph("r2", [range(2, 12)], [])],
            {"shared_features": True, "min_containment": 0.8},
        ),
        (
            "too few shared features keep areas apart",
            [graph("r1", [range(10)], []), graph("r2", [range(2, 12)], [])],
            {"shared_features": True, "min_containment": 0.5, "min_shared": 9},
        ),
        (
            "links do not chain ends that share nothing",
            [
                graph("r1", [range(8)], []),
                graph("r2", [range(20)], []),
                graph("r3", [range(10, 20)], []),
            ],
            {"shared_features": True},
        ),
        (
            "an area seeing into the next room does not join the rooms",
            [
                graph("r1", [room_p, room_q[:10]], [(0, 1, 1, 0)]),
                graph("r2", [room_p, room_q], [(0, 1, 1, 1)]),
                graph("r3", [range(32)], []),
            ],
            {"shared_features": True},
        ),
        (
            "one robot's areas are never linked directly",
            [graph("r1", [range(10), range(10)], [(0, 1, 3, 2)])],
            {"shared_features": True},
        ),
        (
            "boundary features trimmed to the most frequent over robots",
            [
                graph("r1", [room_a, room_b], [(0, 1, 6, 5)]),
                graph("r2", [room_a, room_b], [(0, 1, 2, 0)]),
            ],
            {"shared_features": True, "max_boundary_features": 4},
        ),
        ("no robots", [], {"shared_features": True}),
    ]
    out = []
    for name, graphs, options in cases:
        params = FleetParams(**options)
        fleet = fleet_graph_of(graphs, params)
        out.append(
            {
                "name": name,
                "params": {
                    "shared_features": params.shared_features,
                    "min_containment": params.min_containment,
                    "min_shared": params.min_shared,
                    "min_linked_share": params.min_linked_share,
                    "max_boundary_features": params.max_boundary_features,
                },
                "graphs_hex": [encode(g).hex() for g in graphs],
                "fleet": {
                    **fleet.to_json(),
                    "area_of": [[r, a, f] for (r, a), f in sorted(fleet.area_of.items())],
                },
            }
        )
    return {"type": "fleet_areas", "cases": out}

"""``lessmap areas``: a running fleet's places, from the service's answers.

It asks every robot's area graph of one fleet (the ``areas`` query, wherever each robot's
session lives now), merges them with the SDK's fleet merge (``lessmap_client.fleet_areas``,
the same as ``FleetClient.fleet_area_graph``), prints the fleet areas and passages, and with
``--out`` writes the area-graph file that ``lessmap plot --area-graph`` draws (the layout of
``lessmap segment --area-graph``, so a live fleet and a recorded one read alike).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap_client.cli_options import add_zenoh_options, positive_float, zenoh_options
from lessmap_client.fleet_areas import FleetGraph, FleetParams, fleet_graph

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence

    from lessmap.core.areas.graph import AreaGraph


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap areas``."""
    parser.description = (
        "Show the places of a running fleet: every robot's area graph (areas and the passages "
        "between them, as the service holds them), merged into fleet areas. With "
        "--shared-features (the fleet's feature ids are global: fiducials, a shared landmark "
        "map) robots that have been in the same place share its fleet area; without, each "
        "robot area is a fleet area of its own. --out writes the area-graph file that "
        "`lessmap plot --area-graph FILE --out FIG.png` draws. Fleet ids name this answer's "
        "areas: a later call may number them otherwise (compare members). Exit code 1 when "
        "no robot of the fleet is known to any instance."
    )
    parser.add_argument("--fleet", required=True, help="the fleet")
    parser.add_argument(
        "--shared-features",
        action="store_true",
        help="feature ids are global across the fleet's robots",
    )
    parser.add_argument(
        "-o", "--out", type=Path, metavar="G.json", help="write the area-graph file (G.json)"
    )
    parser.add_argument("--json", action="store_true", help="print the file's JSON object")
    parser.add_argument(
        "--timeout",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="seconds to wait for the instances' answers",
    )
    add_zenoh_options(parser)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap areas``."""
    from lessmap.files.area_graph import area_graph_from_wire, graph_document, write_graph_file

    if "*" in args.fleet:
        sys.stderr.write(f"lessmap areas: --fleet names one fleet, not {args.fleet!r}\n")
        return 1
    net = zenoh_options(args)
    with net.connection() as conn:
        replies = conn.area_graphs(args.fleet, "*", args.timeout)
    if not replies:
        sys.stderr.write(
            f"lessmap areas: no robot of fleet {args.fleet!r} answered at "
            f"{net.where} within {args.timeout:g} s\n"
        )
        return 1
    robots = {reply.robot: area_graph_from_wire(reply) for reply in replies}
    params = FleetParams(shared_features=args.shared_features)
    fleet = fleet_graph(robots, params)
    document = graph_document(robots, fleet, params, f"fleet {args.fleet}")
    if args.out is not None:
        write_graph_file(args.out, document)
    if args.json:
        sys.stdout.write(json.dumps(document) + "\n")
    else:
        methods = sorted({reply.method for reply in replies})
        sys.stdout.write(render(args.fleet, robots, fleet, methods, args.out))
    return 0


def render(
    fleet_name: str,
    robots: dict[str, AreaGraph],
    fleet: FleetGraph,
    methods: Sequence[str],
    out: Path | None,
) -> str:
    """The human summary: one line per fleet area, then one per passage."""
    lines = [
        f"fleet {fleet_name}: {len(robots)} robots ({', '.join(methods)}), "
        f"{sum(len(g.nodes) for g in robots.values())} robot areas, "
        f"{len(fleet.nodes)} fleet areas, {len(fleet.edges)} passages"
    ]
    for node in fleet.nodes:
        members = ", ".join(f"{robot}:{area}" for robot, area in node.members)
        lines.append(
            f"  area {node.area}: {node.features} features, {node.frames} frames, "
            f"{node.visits} visits  [{members}]"
        )
    for edge in fleet.edges:
        doors = " ".join(str(feature) for feature, _ in edge.boundary_features[:4])
        lines.append(
            f"  {edge.a} -> {edge.b}: {edge.a_to_b}, {edge.b} -> {edge.a}: {edge.b_to_a}"
            f"  by {', '.join(edge.robots)}" + (f"  boundary {doors}" if doors else "")
        )
    if out is not None:
        lines.append(f"written to {out} (lessmap plot --area-graph {out} --out FIG.png)")
    return "\n".join(lines) + "\n"

"""The area-graph file (``lessmap segment --method areas --area-graph OUT.json``).

One JSON object, ``{"format": FORMAT, "source", "fleet_params", "robots", "fleet"}``: each
robot's nodes and edges as ``lessmap.core.areas.graph`` defines them, the fleet's as
``lessmap_client.fleet_areas`` does. ``FORMAT`` names the layout and a reader refuses any
other. The layout with an example: ``docs/design/area-graph.md``.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from lessmap.core.areas.graph import AreaEdge, AreaGraph, AreaNode
from lessmap.errors import DatasetError
from lessmap_client.fleet_areas import FleetEdge, FleetGraph, FleetNode, FleetParams

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from lessmap_schemas.messages import AreaGraph as WireAreaGraph

FORMAT = "lessmap.area_graph/1"


def graph_document(
    robots: Mapping[str, AreaGraph], fleet: FleetGraph, params: FleetParams, source: str
) -> dict[str, Any]:
    """Return the robots' graphs and the fleet's as the file's JSON object."""
    return {
        "format": FORMAT,
        "source": source,
        "fleet_params": {
            "shared_features": params.shared_features,
            "min_containment": params.min_containment,
            "min_shared": params.min_shared,
            "min_linked_share": params.min_linked_share,
        },
        "robots": {
            robot: {
                "nodes": [
                    {
                        "area": n.area,
                        "frames": n.frames,
                        "visits": n.visits,
                        "first_seq": n.first_seq,
                        "last_seq": n.last_seq,
                        "features": list(n.features),
                    }
                    for n in graph.nodes
                ],
                "edges": [_edge(e) for e in graph.edges],
            }
            for robot, graph in sorted(robots.items())
        },
        "fleet": fleet.to_json(),
    }


def area_graph_from_wire(message: WireAreaGraph) -> AreaGraph:
    """A robot's graph as the service answered it (the ``areas`` query), in the file's terms."""
    return AreaGraph(
        nodes=tuple(
            AreaNode(
                area=area.id,
                frames=area.frames,
                visits=area.visits,
                first_seq=area.first_seq,
                last_seq=area.last_seq,
                features=tuple(area.features),
            )
            for area in message.areas
        ),
        edges=tuple(
            AreaEdge(
                a=passage.a,
                b=passage.b,
                a_to_b=passage.a_to_b,
                b_to_a=passage.b_to_a,
                boundary_features=tuple((f, n) for f, n in passage.boundary_features),
            )
            for passage in message.passages
        ),
    )


def _edge(edge: AreaEdge) -> dict[str, Any]:
    return {
        "a": edge.a,
        "b": edge.b,
        "a_to_b": edge.a_to_b,
        "b_to_a": edge.b_to_a,
        "boundary_features": [list(pair) for pair in edge.boundary_features],
    }


def write_graph_file(path: Path, document: dict[str, Any]) -> None:
    """Write the document (``graph_document``) as indented JSON."""
    path.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")


def read_graph_file(path: Path) -> tuple[dict[str, AreaGraph], FleetGraph]:
    """Read an area-graph file back.

    Raises:
        FileNotFoundError: no such file.
        DatasetError: not UTF-8 JSON, or not this layout (one line naming the file and fault).
    """
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        msg = f"{path}: not UTF-8 (byte 0x{exc.object[exc.start]:02x} at offset {exc.start})"
        raise DatasetError(msg) from None
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        msg = f"{path}: not JSON: {exc}"
        raise DatasetError(msg) from None
    try:
        if document.get("format") != FORMAT:
            msg = f"format is {document.get('format')!r}, expected {FORMAT!r}"
            raise ValueError(msg)
        robots = {str(r): _robot_graph(g) for r, g in document["robots"].items()}
        fleet = _fleet_graph(document["fleet"])
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        what = f"missing field {exc}" if isinstance(exc, KeyError) else str(exc)
        msg = f"{path}: not an area-graph file ({FORMAT}): {what}"
        raise DatasetError(msg) from None
    return robots, fleet


def _ints(values: Any) -> tuple[int, ...]:
    return tuple(_int(v) for v in values)


def _int(value: Any) -> int:
    if not isinstance(value, int) or isinstance(value, bool):
        msg = f"expected an integer, got {value!r}"
        raise TypeError(msg)
    return value


def _pairs(values: Any) -> tuple[tuple[int, int], ...]:
    pairs = tuple(_ints(pair) for pair in values)
    if any(len(pair) != 2 for pair in pairs):
        msg = "boundary_features must be [feature, count] pairs"
        raise ValueError(msg)
    return tuple((pair[0], pair[1]) for pair in pairs)


def _robot_graph(graph: Any) -> AreaGraph:
    nodes = tuple(
        AreaNode(
            area=_int(n["area"]),
            frames=_int(n["frames"]),
            visits=_int(n["visits"]),
            first_seq=_int(n["first_seq"]),
            last_seq=_int(n["last_seq"]),
            features=_ints(n["features"]),
        )
        for n in graph["nodes"]
    )
    edges = tuple(
        AreaEdge(
            a=_int(e["a"]),
            b=_int(e["b"]),
            a_to_b=_int(e["a_to_b"]),
            b_to_a=_int(e["b_to_a"]),
            boundary_features=_pairs(e["boundary_features"]),
        )
        for e in graph["edges"]
    )
    _check_edges(edges, {n.area for n in nodes})
    return AreaGraph(nodes=nodes, edges=edges)


def _fleet_graph(graph: Any) -> FleetGraph:
    nodes = tuple(
        FleetNode(
            area=_int(n["area"]),
            members=tuple((str(m[0]), _int(m[1])) for m in n["members"]),
            frames=_int(n["frames"]),
            visits=_int(n["visits"]),
            features=_int(n["features"]),
        )
        for n in graph["nodes"]
    )
    edges = tuple(
        FleetEdge(
            a=_int(e["a"]),
            b=_int(e["b"]),
            a_to_b=_int(e["a_to_b"]),
            b_to_a=_int(e["b_to_a"]),
            robots=tuple(str(r) for r in e["robots"]),
            boundary_features=_pairs(e["boundary_features"]),
        )
        for e in graph["edges"]
    )
    _check_edges(edges, {n.area for n in nodes})
    area_of = {member: node.area for node in nodes for member in node.members}
    return FleetGraph(nodes=nodes, edges=edges, area_of=area_of)


def _check_edges(edges: tuple[AreaEdge, ...] | tuple[FleetEdge, ...], areas: set[int]) -> None:
    for edge in edges:
        if edge.a not in areas or edge.b not in areas:
            msg = f"edge {edge.a}-{edge.b} names an area that is not a node"
            raise ValueError(msg)

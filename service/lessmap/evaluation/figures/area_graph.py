"""Draw an area graph (``lessmap plot --area-graph OUT.json --out FIG.png``).

Nodes sit on a circle in id order (an area graph has a handful of nodes; a fixed layout
draws the same file the same way every time), sized by frames; edges are as wide as their
passage count, labelled with it; each node is labelled with its id and frames.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path

    from lessmap.core.areas.graph import AreaGraph
    from lessmap_client.fleet_areas import FleetGraph

NODE_AREA_PT2 = (200.0, 2400.0)  # marker areas of the smallest and the largest node


def draw_area_graph(path: Path, graph: AreaGraph | FleetGraph, title: str) -> Path:
    """Write the graph's figure to ``path`` (PNG, or what its suffix names); return it."""
    from matplotlib.figure import Figure  # never pyplot: no global backend (as plots.py)

    ids = [node.area for node in graph.nodes]
    count = len(ids)
    where = {
        area: (math.cos(2 * math.pi * i / count), math.sin(2 * math.pi * i / count))
        for i, area in enumerate(ids)
    }
    frames = [node.frames for node in graph.nodes]
    low, high = min(frames, default=0), max(frames, default=0)
    span = high - low or 1

    fig = Figure(figsize=(7, 7))
    ax = fig.add_subplot()
    widest = max((edge.passages for edge in graph.edges), default=1)
    for edge in graph.edges:
        (x0, y0), (x1, y1) = where[edge.a], where[edge.b]
        ax.plot([x0, x1], [y0, y1], color="0.45", zorder=1, lw=1 + 7 * edge.passages / widest)
        label = (
            f"{edge.passages} ({edge.a}→{edge.b} {edge.a_to_b}, {edge.b}→{edge.a} {edge.b_to_a})"
        )
        ax.annotate(
            label,
            ((x0 + x1) / 2, (y0 + y1) / 2),
            ha="center",
            fontsize=8,
            bbox={"boxstyle": "round", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    sizes = [
        NODE_AREA_PT2[0] + (NODE_AREA_PT2[1] - NODE_AREA_PT2[0]) * (f - low) / span for f in frames
    ]
    xs = [where[a][0] for a in ids]
    ys = [where[a][1] for a in ids]
    ax.scatter(xs, ys, s=sizes, c="tab:blue", alpha=0.85, zorder=2, edgecolors="white")
    for node in graph.nodes:
        x, y = where[node.area]
        # outside the circle, so that a small node's label stays readable
        ax.annotate(
            f"area {node.area}\n{node.frames} frames",
            (1.2 * x, 1.2 * y),
            ha="center",
            va="center",
            fontsize=9,
            zorder=3,
        )
    ax.set_title(title)
    ax.set_aspect("equal")
    ax.set_xlim(-1.45, 1.45)
    ax.set_ylim(-1.45, 1.45)
    ax.axis("off")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    return path

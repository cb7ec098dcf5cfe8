r"""Draw the channels of a ``lessmap record`` MCAP file as Foxglove's panels would lay them out.

This is not the Foxglove app: it reads the file back (``mcap``, ``mcap-protobuf-support``),
decodes every message the way any MCAP reader would, and draws with matplotlib what the 3D
panel (``/lessmap/scene``, ``/lessmap/covgraph`` seen from above), the Log panel
(``/lessmap/transitions``) and the Table panel (``/lessmap/state``) hold at the end of the
recording. ``docs/figures/foxglove-view.png`` was made so, from ``foxglove-view.mcap``::

    lessmap serve -m router -l tcp/127.0.0.1:17931 --memory-only &
    lessmap record --fleet demo -e tcp/127.0.0.1:17931 --mcap foxglove-view.mcap \\
        --covgraph robot0 &
    lessmap sim --publish --fleet demo -e tcp/127.0.0.1:17931 --robots 3 --rooms 8 --speed 40
    kill -TERM %2 %1
    pip install mcap mcap-protobuf-support matplotlib
    python docs/figures/render_mcap.py foxglove-view.mcap --out docs/figures/foxglove-view.png
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path
from typing import Any


def read_channels(path: Path) -> dict[str, list[Any]]:
    """Return every message of the file by topic, decoded (protobuf or JSON), in log order."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    factory = DecoderFactory()
    found: dict[str, list[Any]] = {}
    with path.open("rb") as handle:
        for schema, channel, message in make_reader(handle).iter_messages(log_time_order=True):
            if channel.message_encoding == "json":
                decoded: Any = json.loads(message.data)
            else:
                decoder = factory.decoder_for(channel.message_encoding, schema)
                assert decoder is not None, channel.topic
                decoded = decoder(message.data)
            found.setdefault(channel.topic, []).append(decoded)
    return found


def latest_entities(updates: list[Any]) -> dict[str, Any]:
    """Return the newest version of each scene entity (what a 3D panel shows at the end)."""
    entities: dict[str, Any] = {}
    for update in updates:
        for entity in update.entities:
            entities[entity.id] = entity
    return entities


def rgba(color: Any) -> tuple[float, float, float, float]:
    """Return a Foxglove colour as a matplotlib RGBA tuple."""
    return (color.r, color.g, color.b, color.a)


def draw(channels: dict[str, list[Any]], out: Path) -> None:
    """Draw the three panels and save the figure."""
    import matplotlib as mpl

    mpl.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    plt.rcParams.update({"font.size": 9, "text.color": "#e6e6e6", "axes.labelcolor": "#e6e6e6"})
    fig = plt.figure(figsize=(15, 7.5), facecolor="#15151b")
    grid = fig.add_gridspec(2, 2, width_ratios=[1.5, 1], height_ratios=[1.3, 1], wspace=0.06)
    scene = fig.add_subplot(grid[:, 0], facecolor="#1e1e26")
    logs = fig.add_subplot(grid[0, 1], facecolor="#1e1e26")
    table = fig.add_subplot(grid[1, 1], facecolor="#1e1e26")

    entities = latest_entities(channels.get("/lessmap/scene", []))
    graph = latest_entities(channels.get("/lessmap/covgraph", []))
    for entity in [*graph.values(), *entities.values()]:
        for line in entity.lines:
            points = [(p.x, p.y) for p in line.points]
            colours = [rgba(c) for c in line.colors] or [rgba(line.color)] * len(points)
            if line.type == 0:  # LINE_STRIP: consecutive points (1 is LINE_LOOP, 2 LINE_LIST)
                segments = list(itertools.pairwise(points))
                colours = colours[1:]
                width = 2.0
            else:  # LINE_LIST: pairs
                segments = list(zip(points[::2], points[1::2], strict=True))
                colours = colours[1::2]
                width = 0.5
            scene.add_collection(LineCollection(segments, colors=colours, linewidths=width))
        for sphere in entity.spheres:
            position = sphere.pose.position
            scene.scatter(
                [position.x],
                [position.y],
                s=900 * sphere.size.x**2,
                color=[rgba(sphere.color)],
                edgecolors="none",
                zorder=3,
            )
        for text in entity.texts:
            position = text.pose.position
            scene.text(
                position.x, position.y, text.text, color=rgba(text.color), fontsize=8, zorder=4
            )
    scene.set_aspect("equal")
    scene.autoscale_view()
    scene.tick_params(colors="#8a8a99")
    for spine in scene.spines.values():
        spine.set_color("#33333f")
    scene.set_title(
        "3D panel, top view — /lessmap/scene" + (" + /lessmap/covgraph" if graph else ""),
        color="#e6e6e6",
        loc="left",
    )

    entries = channels.get("/lessmap/transitions", [])
    logs.axis("off")
    logs.set_title(
        f"Log panel — /lessmap/transitions (last 14 of {len(entries)})", color="#e6e6e6", loc="left"
    )
    lines = [entry.message for entry in entries[-14:]]
    logs.text(
        0.0,
        1.0,
        "\n".join(line if len(line) < 100 else line[:97] + "..." for line in lines),
        family="monospace",
        fontsize=7.2,
        va="top",
        transform=logs.transAxes,
    )

    states = channels.get("/lessmap/state", [])
    table.axis("off")
    table.set_title(
        "Table panel — /lessmap/state.robots (last message)", color="#e6e6e6", loc="left"
    )
    if states:
        rows = states[-1]["robots"]
        columns = ["robot", "frames_applied", "frames_missing", "transitions", "submap", "nodes"]
        labels = ["robot", "applied", "missing", "transitions", "submap", "nodes"]
        cells = [[str(row[c]) for c in columns] for row in rows]
        drawn = table.table(cellText=cells, colLabels=labels, loc="upper left", cellLoc="center")
        drawn.auto_set_font_size(False)
        drawn.set_fontsize(8)
        drawn.scale(1.0, 1.6)
        for cell in drawn.get_celld().values():
            cell.set_facecolor("#26262f")
            cell.set_edgecolor("#44444f")
            cell.get_text().set_color("#e6e6e6")

    fig.suptitle(
        "Rendering of the channels lessmap record wrote to MCAP, read back from the file "
        "(not a screenshot of the Foxglove app)",
        color="#e6e6e6",
        fontsize=11,
    )
    fig.savefig(out, dpi=90, facecolor=fig.get_facecolor(), bbox_inches="tight")


def main() -> None:
    """Read the MCAP file given, write the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mcap", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    draw(read_channels(args.mcap), args.out)


if __name__ == "__main__":
    main()

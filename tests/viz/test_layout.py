"""The shipped Foxglove/Lichtblick layout names the channels the viewer serves."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lessmap.viz.scene import (
    COVGRAPH_TOPIC,
    FRAME_ID,
    SCENE_TOPIC,
    STATE_SCHEMA,
    STATE_TOPIC,
    TRANSITIONS_TOPIC,
)

LAYOUT = Path(__file__).resolve().parents[2] / "docs" / "foxglove" / "lessmap-layout.json"


def panels(layout: dict[str, Any]) -> list[str]:
    """Return the panel ids of the layout tree, in order."""
    found: list[str] = []

    def walk(node: Any) -> None:
        if isinstance(node, str):
            found.append(node)
        else:
            walk(node["first"])
            walk(node["second"])

    walk(layout["layout"])
    return found


def test_the_layout_shows_every_channel_in_the_map_frame() -> None:
    layout = json.loads(LAYOUT.read_text(encoding="utf-8"))
    config = layout["configById"]
    assert sorted(panels(layout)) == sorted(config)
    (three_d,) = (v for k, v in config.items() if k.startswith("3D!"))
    (table,) = (v for k, v in config.items() if k.startswith("Table!"))
    (log,) = (v for k, v in config.items() if k.startswith("RosOut!"))  # the Log panel
    assert three_d["followTf"] == FRAME_ID
    assert set(three_d["topics"]) == {SCENE_TOPIC, COVGRAPH_TOPIC}
    assert all(topic["visible"] for topic in three_d["topics"].values())
    path, field = table["topicPath"].split(".")
    assert path == STATE_TOPIC
    assert field in STATE_SCHEMA["properties"]
    assert log["topicToRender"] == TRANSITIONS_TOPIC


def test_the_layout_is_not_tied_to_one_building() -> None:
    three_d = next(
        v for k, v in json.loads(LAYOUT.read_text())["configById"].items() if k.startswith("3D!")
    )
    camera = three_d["cameraState"]
    assert camera["target"] == camera["targetOffset"] == [0, 0, 0]
    assert "position" not in three_d["layers"]["grid"]  # centred on the map origin

"""The shipped Foxglove/Lichtblick layout names the channels the viewer serves."""

from __future__ import annotations

import json
import math
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


def azimuth_after_a_wheel_step(phi_deg: float, theta_offset_deg: float) -> float:
    """Return the thetaOffset (degrees) Lichtblick's 3D panel reads back after a zoom step.

    Replays its CameraStateSettings (1.x) with three.js' conventions: the orbit camera is put
    at the spherical point (r, phi, theta = -thetaOffset) of a Y-up frame turned +90° about X
    into the panel's Z-up world; OrbitControls turns the offset back to Y-up and reads the
    azimuth as atan2(x, z); the panel stores thetaOffset = -azimuth and turns its 2D
    (orthographic) camera by it. At phi = 0 the point sits on the pole, x and z are only
    rounding noise, and atan2 can answer 180°: the 2D view flips on the first wheel step.
    """
    r = 20.0
    phi = math.radians(phi_deg)
    theta = -math.radians(theta_offset_deg)
    # setFromSpherical (three.js): x = r sinφ sinθ, y = r cosφ, z = r sinφ cosθ
    x, y, z = (
        r * math.sin(phi) * math.sin(theta),
        r * math.cos(phi),
        r * math.sin(phi) * math.cos(theta),
    )
    # applyAxisAngle(UNIT_X, π/2), with the same floating-point cos(π/2) as JavaScript
    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    y, z = y * c - z * s, y * s + z * c
    # OrbitControls: quaternion from up (0, 0, 1) to (0, 1, 0) maps (x, y, z) -> (x, z, -y)
    x, y, z = x, z, -y
    return -math.degrees(math.atan2(x, z))


def test_the_top_view_keeps_its_heading_when_zoomed() -> None:
    three_d = next(
        v for k, v in json.loads(LAYOUT.read_text())["configById"].items() if k.startswith("3D!")
    )
    camera = three_d["cameraState"]
    assert camera["perspective"] is False  # the 2D view: top-down, polar angle locked
    assert 0 < camera["phi"] <= 1  # off the pole, and still top-down when switched to 3D
    assert camera["thetaOffset"] == 0  # map x to the right, y up
    heading = azimuth_after_a_wheel_step(camera["phi"], camera["thetaOffset"])
    assert abs(heading - camera["thetaOffset"]) < 1e-6


def test_a_camera_on_the_pole_flips_the_2d_view() -> None:
    """The replay reproduces the flip seen in Lichtblick with phi 0 (the earlier layout)."""
    assert abs(azimuth_after_a_wheel_step(0.0, 0.0)) == 180

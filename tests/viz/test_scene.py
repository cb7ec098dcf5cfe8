"""The scene's doorway labels, their colours, and the ``map`` frame."""

from __future__ import annotations

import math

import pytest

from lessmap.viz.model import FleetModel
from lessmap.viz.scene import (
    DOORWAY_RADIUS_M,
    FRAME_ID,
    PALETTE,
    doorway_entity,
    doorways,
    fleet_entities,
    label_color,
    map_transform,
    track_entities,
    transition_log,
)
from lessmap_schemas.messages import Frame
from tests.viz.conftest import decode
from tests.viz.test_model import transition


def lichtblick_luminance(c: dict[str, float]) -> float:
    """Lichtblick 1.28's getLuminance: its labels get a white box below 0.5, black above."""
    return math.hypot(0.5468 * c["r"], 0.7662 * c["g"], 0.3376 * c["b"])


def cross(model: FleetModel, robot: str, door_at: tuple[float, float], opened: int) -> None:
    """Walk ``robot`` through a door at ``door_at`` and let its transition arrive."""
    track = model.tracks.get(robot)
    start = track.last_seq + 1 if track is not None else 0
    x, y = door_at
    for k in range(4):
        model.on_frame(
            robot,
            Frame(session="s", seq=start + k, stamp_s=start + k, features=[k], pose=(x, y, 0.0)),
        )
    assert model.on_transition(transition(robot, "s", start + 2, opened)) is not None


def test_transitions_at_one_door_share_one_label_whoever_made_them() -> None:
    model = FleetModel("f")
    cross(model, "amr1", (5.0, 2.0), 1)
    cross(model, "amr2", (5.2, 2.1), 1)  # the same door, 0.2 m away
    cross(model, "amr1", (9.0, 2.0), 2)  # the next door
    cross(model, "amr3", (5.1, 1.8), 1)  # the first door again, last of all
    found = doorways(model.tracks.values())
    assert [(d.robot, d.count) for d in found] == [("amr3", 3), ("amr1", 1)]
    entity = decode(doorway_entity(found))
    assert entity["id"] == "doorways"
    assert entity["frame_id"] == FRAME_ID
    assert [t["text"] for t in entity["texts"]] == ["amr3 0→1 (+2)", "amr1 1→2"]
    assert len(entity["spheres"]) == 2


@pytest.mark.parametrize("offset_m", [0.5, 0.99 * DOORWAY_RADIUS_M, 1.5 * DOORWAY_RADIUS_M])
def test_doors_are_merged_within_the_radius_only(offset_m: float) -> None:
    model = FleetModel("f")
    cross(model, "a", (0.0, 0.0), 1)
    # Diagonal and across a grid line: the neighbouring cells are searched too.
    cross(model, "b", (-offset_m / math.sqrt(2), offset_m / math.sqrt(2)), 1)
    expected = 1 if offset_m <= DOORWAY_RADIUS_M else 2
    assert len(doorways(model.tracks.values())) == expected


def test_a_transition_is_placed_once_its_boundary_frame_arrives() -> None:
    model = FleetModel("f")
    mark = model.on_transition(transition("r", "s", 3, 1))  # history, before any frame
    assert mark is not None
    assert mark.at is None
    assert doorways(model.tracks.values()) == []
    for seq in range(5):
        pose = (float(seq), 1.0, 0.0)
        model.on_frame("r", Frame(session="s", seq=seq, stamp_s=seq, features=[seq], pose=pose))
    (door,) = doorways(model.tracks.values())
    assert (door.x, door.y) == (3, 1)


def test_labels_are_light_on_a_dark_box_small_and_keep_the_submap_hue() -> None:
    for submap in range(len(PALETTE)):
        text = decode(label_color(submap))
        assert lichtblick_luminance(text) > 0.5  # Lichtblick draws a black box behind it
        r, g, b = PALETTE[submap]
        hue = max(range(3), key=lambda i: (r, g, b)[i])
        assert max(("r", "g", "b"), key=lambda k: text[k]) == "rgb"[hue]
    model = FleetModel("f")
    cross(model, "amr1", (5.0, 2.0), 1)
    (door_text,) = decode(doorway_entity(doorways(model.tracks.values())))["texts"]
    (robot_text,) = decode(track_entities(model.tracks["amr1"])[0])["texts"]
    assert door_text["font_size"] < robot_text["font_size"]
    assert door_text["scale_invariant"]


def test_the_map_frame_is_a_root_with_a_child() -> None:
    transform = decode(map_transform())
    assert transform["parent_frame_id"] == FRAME_ID == "map"
    assert transform["child_frame_id"] not in ("", FRAME_ID)
    assert transform["rotation"]["w"] == 1.0


def test_the_whole_scene_has_every_robot_and_the_doorways() -> None:
    model = FleetModel("f")
    cross(model, "amr1", (5.0, 2.0), 1)
    cross(model, "amr2", (5.0, 6.0), 1)
    ids = [decode(e)["id"] for e in fleet_entities(model)]
    assert ids == ["amr1/trajectory", "amr2/trajectory", "doorways"]


def test_the_log_names_the_areas_and_says_why_in_words() -> None:
    model = FleetModel("f")
    cross(model, "amr1", (1.0, 0.0), 1)
    [first] = model.tracks["amr1"].marks
    assert b"amr1: area 0 -> area 1 from seq" in transition_log("amr1", first).encode()
    back = transition("amr1", "s", 6, 2).model_copy(
        update={"reason": "RECOGNISED", "area": 0, "left_area": 1, "revisit": True}
    )
    back = back.model_copy(update={"batch_frames": 5})
    mark = model.on_transition(back)
    assert mark is not None
    text = transition_log("amr1", mark).encode().decode("utf-8", errors="replace")  # protobuf
    assert "amr1: area 1 -> area 0 again from seq 6" in text
    assert "RECOGNISED, its last frames fit an area it mapped before" in text
    assert "fell apart" not in text
    assert "; decided over 5 coalesced frames" in text

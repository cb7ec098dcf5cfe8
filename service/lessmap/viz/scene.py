"""The fleet as Foxglove messages, on fixed channels (the same live and in an MCAP file).

- ``/lessmap/scene`` (``foxglove.SceneUpdate``): per robot, its current session's trajectory
  coloured by submap (where frames carry poses), its current pose and label, and the line of
  the session it had before, dimmed; for the fleet, one sphere and one label per doorway
  (transitions within ``DOORWAY_RADIUS_M`` of each other, any robot: the latest one, and how
  many others happened there), so that robots crossing one door many times share one label.
- ``/lessmap/transitions`` (``foxglove.Log``): one entry per transition: robot, the areas
  it crossed, seq, the reason in words, the submaps.
- ``/lessmap/state`` (JSON): the per-robot state table: session, frames applied / missing /
  rejected, transitions, current submap, CovGraph size, instance.
- ``/lessmap/covgraph`` (``foxglove.SceneUpdate``, optional): the CovGraph of one robot's
  current submap (features at the mean pose of the frames that saw them; edges shaded by
  CovRate).
- ``/lessmap/tf`` (``foxglove.FrameTransform``): a fixed transform ``map`` → ``lessmap``,
  so that the 3D panel has its display frame ``map`` before the first scene message.

Everything is in the frame ``map`` (the robots' odometry frames, as the frames give them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from foxglove.messages import (
    Color,
    FrameTransform,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from lessmap_client.watch import areas_crossed, coalesced, why

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from lessmap.viz.model import CovGraph, FleetModel, Mark, Track
    from lessmap_client.fleet_areas import FleetGraph
    from lessmap_schemas.messages import SessionState

FRAME_ID = "map"
SCENE_TOPIC = "/lessmap/scene"
TRANSITIONS_TOPIC = "/lessmap/transitions"
STATE_TOPIC = "/lessmap/state"
COVGRAPH_TOPIC = "/lessmap/covgraph"
TF_TOPIC = "/lessmap/tf"
#: The child of the fixed ``map`` transform (nothing is drawn in it).
ROOT_CHILD_FRAME = "lessmap"

#: Transitions this close to each other are one doorway (one label). In the sim's 8-room
#: building, doors are 1 m wide and at least 3.6 m apart, and robots crossing one door put
#: their transitions within 0.3 m of each other.
DOORWAY_RADIUS_M = 1.0
#: How far doorway labels are mixed toward white (see ``label_color``).
LABEL_LIGHTEN = 0.65
PREVIOUS_SESSION_COLOR = Color(r=0.6, g=0.6, b=0.6, a=0.35)

#: Submap colours (matplotlib's tab10), cycled by submap id.
PALETTE = [
    (0.122, 0.467, 0.706),
    (1.000, 0.498, 0.055),
    (0.173, 0.627, 0.173),
    (0.839, 0.153, 0.157),
    (0.580, 0.404, 0.741),
    (0.549, 0.337, 0.294),
    (0.890, 0.467, 0.761),
    (0.498, 0.498, 0.498),
    (0.737, 0.741, 0.133),
    (0.090, 0.745, 0.812),
]

#: JSON schema of the state table: one row per robot (Foxglove's Table panel shows it).
STATE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "lessmap.FleetState",
    "properties": {
        "fleet": {"type": "string"},
        "robots": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    name: {"type": kind}
                    for name, kind in (
                        ("robot", "string"),
                        ("session", "string"),
                        ("open", "boolean"),
                        ("frames_applied", "integer"),
                        ("frames_missing", "integer"),
                        ("frames_rejected", "integer"),
                        ("transitions", "integer"),
                        ("submap", "integer"),
                        ("method", "string"),
                        ("area", "integer"),
                        ("place", "string"),
                        ("nodes", "integer"),
                        ("edges", "integer"),
                        ("instance", "string"),
                    )
                },
            },
        },
    },
}


def color(submap: int, alpha: float = 1.0) -> Color:
    """Return the colour of a submap."""
    r, g, b = PALETTE[submap % len(PALETTE)]
    return Color(r=r, g=g, b=b, a=alpha)


def stamp(seconds: float) -> Timestamp:
    """Return a Foxglove timestamp (clamped at 0: robots' clocks may start anywhere)."""
    return Timestamp.from_epoch_secs(max(0.0, seconds))


def _pose(x: float, y: float, theta: float = 0.0) -> Pose:
    return Pose(
        position=Vector3(x=x, y=y, z=0.0),
        orientation=Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2)),
    )


def track_entities(track: Track) -> list[SceneEntity]:
    """Return a robot's trajectory, current pose and label (one entity, ``ROBOT/trajectory``).

    A track without poses gives the entity with no primitives: it replaces, and so clears,
    the line of the robot's earlier session until the new session's first pose.
    """
    points = list(track.points)
    if not points:
        return [SceneEntity(frame_id=FRAME_ID, id=f"{track.robot}/trajectory")]
    colours = [color(track.submap_of(p.seq)) for p in points]
    last = points[-1]
    return [
        SceneEntity(
            timestamp=stamp(last.stamp_s),
            frame_id=FRAME_ID,
            id=f"{track.robot}/trajectory",
            metadata=[KeyValuePair(key="session", value=track.session)],
            lines=[
                LinePrimitive(
                    type=LinePrimitiveLineType.LineStrip,
                    pose=_pose(0.0, 0.0),
                    thickness=0.05,
                    points=[Point3(x=p.x, y=p.y, z=0.0) for p in points],
                    colors=colours,
                )
            ],
            spheres=[
                SpherePrimitive(
                    pose=_pose(last.x, last.y), size=Vector3(x=0.3, y=0.3, z=0.3), color=colours[-1]
                )
            ],
            texts=[
                TextPrimitive(
                    pose=_pose(last.x, last.y + 0.4),
                    billboard=True,
                    font_size=13.0,
                    scale_invariant=True,
                    color=Color(r=1.0, g=1.0, b=1.0, a=1.0),
                    text=f"{track.robot} · submap {track.submap_of(last.seq)}",
                )
            ],
        )
    ]


def previous_entity(track: Track) -> SceneEntity:
    """Return the dimmed line of the session a robot left (``ROBOT/previous``).

    Grey, thin and unlabelled: it shows where the robot went before, but its submaps are not
    the current session's (ids restart at 0, so submap colours would clash), and its
    transitions are not drawn.
    """
    points = list(track.points)
    return SceneEntity(
        timestamp=stamp(points[-1].stamp_s if points else 0.0),
        frame_id=FRAME_ID,
        id=f"{track.robot}/previous",
        metadata=[KeyValuePair(key="session", value=track.session)],
        lines=[
            LinePrimitive(
                type=LinePrimitiveLineType.LineStrip,
                pose=_pose(0.0, 0.0),
                thickness=0.03,
                points=[Point3(x=p.x, y=p.y, z=0.0) for p in points],
                color=PREVIOUS_SESSION_COLOR,
            )
        ]
        if len(points) >= 2
        else [],
    )


@dataclass(frozen=True, slots=True)
class Doorway:
    """Transitions that happened at one place (a doorway, usually), whatever the robot."""

    x: float
    y: float
    robot: str  # of the latest transition here
    latest: Mark
    count: int


def doorways(tracks: Iterable[Track], radius_m: float = DOORWAY_RADIUS_M) -> list[Doorway]:
    """Group the current sessions' transitions by place: one doorway per ``radius_m``.

    In arrival order, a transition joins the nearest doorway whose first transition is
    within ``radius_m`` of it, or starts a new one. A grid of ``radius_m`` cells keeps this
    linear in the number of transitions.
    """
    placed: list[tuple[Mark, str, float, float]] = []
    for track in tracks:
        for mark in track.marks:
            # Looked up again: the boundary frame may have arrived after the transition.
            at = mark.at or track.pose_at(mark.boundary_seq)
            if at is not None:
                placed.append((mark, track.robot, at.x, at.y))
    placed.sort(key=lambda item: item[0].order)
    found: list[Doorway] = []
    grid: dict[tuple[int, int], list[int]] = {}
    for mark, robot, x, y in placed:
        cx, cy = math.floor(x / radius_m), math.floor(y / radius_m)
        near = [
            (distance, i)
            for dx in (-1, 0, 1)
            for dy in (-1, 0, 1)
            for i in grid.get((cx + dx, cy + dy), [])
            if (distance := math.hypot(found[i].x - x, found[i].y - y)) <= radius_m
        ]
        if near:
            door = found[min(near)[1]]
            found[min(near)[1]] = Doorway(door.x, door.y, robot, mark, door.count + 1)
        else:
            grid.setdefault((cx, cy), []).append(len(found))
            found.append(Doorway(x, y, robot, mark, 1))
    return found


def doorway_label(door: Doorway) -> str:
    """Return a doorway's label: its latest transition, and how many others happened there."""
    text = f"{door.robot} {door.latest.closed}→{door.latest.opened}"
    return text if door.count == 1 else f"{text} (+{door.count - 1})"


def label_color(submap: int) -> Color:
    """Return a submap's colour lightened for text.

    Lichtblick draws a label's box white behind dark text and black behind light text; the
    submap colours are dark by its measure, so their text sat on a white box, hard to read.
    Mixed 65 % toward white they are light: the box is black and the hue still tells the
    submap.
    """
    r, g, b = PALETTE[submap % len(PALETTE)]
    mix = LABEL_LIGHTEN
    return Color(r=r + (1 - r) * mix, g=g + (1 - g) * mix, b=b + (1 - b) * mix, a=1.0)


def doorway_entity(found: list[Doorway]) -> SceneEntity:
    """Return every doorway as one sphere and one label (the entity ``doorways``)."""
    return SceneEntity(
        timestamp=stamp(max((d.latest.stamp_s for d in found), default=0.0)),
        frame_id=FRAME_ID,
        id="doorways",
        spheres=[
            SpherePrimitive(
                pose=_pose(d.x, d.y),
                size=Vector3(x=0.4, y=0.4, z=0.4),
                color=color(d.latest.opened, 0.8),
            )
            for d in found
        ],
        texts=[
            TextPrimitive(
                pose=_pose(d.x, d.y - 0.45),
                billboard=True,
                font_size=11.0,
                scale_invariant=True,
                color=label_color(d.latest.opened),
                text=doorway_label(d),
            )
            for d in found
        ],
    )


def robot_entities(model: FleetModel, robot: str) -> list[SceneEntity]:
    """Return a robot's entities: its current track and, if it had one, its previous one."""
    entities = track_entities(model.tracks[robot])
    left = model.previous.get(robot)
    if left is not None:
        entities.append(previous_entity(left))
    return entities


def fleet_entities(model: FleetModel) -> list[SceneEntity]:
    """Return the whole scene: every robot's entities and the doorways."""
    entities: list[SceneEntity] = []
    for robot in sorted(model.tracks):
        entities += robot_entities(model, robot)
    entities.append(doorway_entity(doorways(model.tracks.values())))
    return entities


def map_transform() -> FrameTransform:
    """Return a fixed transform from ``map`` to a child frame, so that ``map`` exists.

    The 3D panel only knows frames from transforms and from messages it has received: without
    this it shows "Display frame map not found" until the first scene message.
    """
    return FrameTransform(
        timestamp=Timestamp(sec=0, nsec=0),
        parent_frame_id=FRAME_ID,
        child_frame_id=ROOT_CHILD_FRAME,
        translation=Vector3(x=0.0, y=0.0, z=0.0),
        rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
    )


def transition_log(robot: str, mark: Mark) -> Log:
    """Return the log entry of one transition: the areas crossed, where, and why."""
    where = f" at ({mark.at.x:.1f}, {mark.at.y:.1f})" if mark.at is not None else ""
    crossed = areas_crossed(mark.left_area, mark.area, revisit=mark.revisit)
    return Log(
        timestamp=stamp(mark.stamp_s),
        level=LogLevel.Info,
        message=(
            f"{robot}: {crossed} from seq {mark.boundary_seq} (detected at {mark.seq})"
            f"{where}: {mark.reason}, {why(mark.reason, mark.ncut, mark.lambda2)}; "
            f"submap {mark.closed} → {mark.opened}{coalesced(mark.batch_frames)}"
        ),
        name=robot,
        file="lessmap",
        line=0,
    )


def state_table(
    fleet: str, states: list[SessionState], places: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """Return the state table message: one row per robot, by name.

    ``places`` (robot -> its fleet area's name, ``robot:area`` of its first member; from
    ``fleet_area_graph`` when the fleet's feature ids are global) adds a ``place`` column.
    """
    rows = [
        {
            "robot": s.robot,
            "session": s.session,
            "open": s.open,
            "frames_applied": s.frames_applied,
            "frames_missing": s.frames_missing,
            "frames_rejected": s.frames_rejected,
            "transitions": s.transitions,
            "submap": s.current_submap.id,
            "method": s.method,
            "area": s.current_area,
            "nodes": s.nodes,
            "edges": s.edges,
            "instance": s.instance,
        }
        | ({} if places is None else {"place": places.get(s.robot, "")})
        for s in sorted(states, key=lambda s: s.robot)
    ]
    return {"fleet": fleet, "robots": rows}


def places_of(states: list[SessionState], graph: FleetGraph) -> dict[str, str]:
    """Each robot's place: the name of its current area's fleet area (``FleetGraph.key_of``).

    A robot whose current area the graph does not hold yet (the two answers are a moment
    apart) has no place until the next graph.
    """
    places = {}
    for s in states:
        if (s.robot, s.current_area) in graph.area_of:
            robot, area = graph.key_of(s.robot, s.current_area)
            places[s.robot] = f"{robot}:{area}"
    return places


def covgraph_entity(robot: str, graph: CovGraph, stamp_s: float) -> SceneEntity:
    """Return the CovGraph as spheres (features) and lines (edges, alpha = CovRate)."""
    placed: dict[int, tuple[float, float]] = {}
    n = max(1, len(graph.nodes))
    for index, (feature, (_count, where)) in enumerate(graph.nodes.items()):
        if where is None:  # no poses: a circle, in feature order
            angle = 2 * math.pi * index / n
            where = (5.0 * math.cos(angle), 5.0 * math.sin(angle))
        placed[feature] = where
    top = max((count for count, _ in graph.nodes.values()), default=1)
    spheres = [
        SpherePrimitive(
            pose=_pose(*placed[f]),
            size=Vector3(x=s, y=s, z=s),
            color=Color(r=0.9, g=0.9, b=0.2, a=1.0),
        )
        for f, (count, _) in graph.nodes.items()
        for s in (0.1 + 0.2 * count / top,)
    ]
    points: list[Point3] = []
    colours: list[Color] = []
    for (i, j), (_a, w) in graph.edges.items():
        for f in (i, j):
            x, y = placed[f]
            points.append(Point3(x=x, y=y, z=0.0))
            colours.append(Color(r=0.3, g=0.8, b=1.0, a=0.15 + 0.85 * w))
    lines = (
        [
            LinePrimitive(
                type=LinePrimitiveLineType.LineList,
                pose=_pose(0.0, 0.0),
                thickness=0.02,
                points=points,
                colors=colours,
            )
        ]
        if points
        else []
    )
    return SceneEntity(
        timestamp=stamp(stamp_s),
        frame_id=FRAME_ID,
        id=f"{robot}/covgraph",
        spheres=spheres,
        lines=lines,
    )


def scene(entities: list[SceneEntity]) -> SceneUpdate:
    """Return a scene update replacing the given entities."""
    return SceneUpdate(entities=entities)

"""The fleet as Foxglove messages, on fixed channels (the same live and in an MCAP file).

- ``/lessmap/scene`` (``foxglove.SceneUpdate``): per robot, its trajectory coloured by submap
  (where frames carry poses), its current pose, a sphere and a label at every transition.
- ``/lessmap/transitions`` (``foxglove.Log``): one entry per transition: robot, submaps, seq,
  reason, Ncut, λ2.
- ``/lessmap/state`` (JSON): the per-robot state table: session, frames applied / missing /
  rejected, transitions, current submap, CovGraph size, instance.
- ``/lessmap/covgraph`` (``foxglove.SceneUpdate``, optional): the CovGraph of one robot's
  current submap (features at the mean pose of the frames that saw them; edges shaded by
  CovRate).

Everything is in the frame ``map`` (the robots' odometry frames, as the frames give them).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from foxglove.messages import (
    Color,
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

if TYPE_CHECKING:
    from lessmap.viz.model import CovGraph, Mark, Track
    from lessmap_schemas.messages import SessionState

FRAME_ID = "map"
SCENE_TOPIC = "/lessmap/scene"
TRANSITIONS_TOPIC = "/lessmap/transitions"
STATE_TOPIC = "/lessmap/state"
COVGRAPH_TOPIC = "/lessmap/covgraph"

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
    """Return a robot's trajectory, current pose and transition marks (empty without poses)."""
    points = list(track.points)
    if not points:
        return []
    colours = [color(track.submap_of(p.seq)) for p in points]
    last = points[-1]
    entities = [
        SceneEntity(
            timestamp=stamp(last.stamp_s),
            frame_id=FRAME_ID,
            id=f"{track.robot}/trajectory",
            metadata=None,
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
                    font_size=14.0,
                    scale_invariant=True,
                    color=Color(r=1.0, g=1.0, b=1.0, a=1.0),
                    text=f"{track.robot} · submap {track.submap_of(last.seq)}",
                )
            ],
        )
    ]
    # A mark's pose is looked up again: its frame may have arrived after the transition.
    marks = [(m, m.at or track.pose_at(m.boundary_seq)) for m in track.marks]
    placed = [(m, at) for m, at in marks if at is not None]
    if placed:
        entities.append(
            SceneEntity(
                timestamp=stamp(last.stamp_s),
                frame_id=FRAME_ID,
                id=f"{track.robot}/transitions",
                spheres=[
                    SpherePrimitive(
                        pose=_pose(at.x, at.y),
                        size=Vector3(x=0.5, y=0.5, z=0.5),
                        color=color(m.opened, 0.8),
                    )
                    for m, at in placed
                ],
                texts=[
                    TextPrimitive(
                        pose=_pose(at.x, at.y - 0.5),
                        billboard=True,
                        font_size=12.0,
                        scale_invariant=True,
                        color=color(m.opened),
                        text=f"{m.closed}→{m.opened} @{m.boundary_seq}",
                    )
                    for m, at in placed
                ],
            )
        )
    return entities


def transition_log(robot: str, mark: Mark) -> Log:
    """Return the log entry of one transition."""
    detail = (
        f"Ncut {mark.ncut:.3f}, λ2 {mark.lambda2:.3f}"
        if mark.ncut is not None and mark.lambda2 is not None
        else "the CovGraph fell apart"
    )
    where = f" at ({mark.at.x:.1f}, {mark.at.y:.1f})" if mark.at is not None else ""
    return Log(
        timestamp=stamp(mark.stamp_s),
        level=LogLevel.Info,
        message=(
            f"{robot}: submap {mark.closed} → {mark.opened} from seq {mark.boundary_seq} "
            f"(detected at {mark.seq}){where}: {mark.reason}, {detail}"
        ),
        name=robot,
        file="lessmap",
        line=0,
    )


def state_table(fleet: str, states: list[SessionState]) -> dict[str, Any]:
    """Return the state table message: one row per robot, by name."""
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
            "nodes": s.nodes,
            "edges": s.edges,
            "instance": s.instance,
        }
        for s in sorted(states, key=lambda s: s.robot)
    ]
    return {"fleet": fleet, "robots": rows}


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

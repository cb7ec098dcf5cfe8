"""Offline ROS input: landmark topics of rosbag2 (sqlite3, MCAP) and ROS 1 bags to frames.

rosbags' ``AnyReader`` opens either kind and registers the message definitions the bag
carries (ROS 1 bags and MCAP always, sqlite3 bags from Iron on); lessmap's own detector
types are the fallback. Messages are read in time order across topics, so the latest pose
of a robot goes with each of its frames exactly as the live bridge would send it. The frames
file is the neutral format every offline tool and ``lessmap replay`` read.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from lessmap.errors import ConfigError
from lessmap.progress import NO_PROGRESS, tracked

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from rosbags.highlevel import AnyReader

    from lessmap.progress import Progress
    from lessmap.ros.convert import Converter

log = logging.getLogger(__name__)


@dataclass
class ImportStats:
    """What an import wrote: frames per robot, and the topics it read."""

    frames: dict[str, int] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)  # topic -> type, landmarks and poses


def robot_of(topic: str, pattern: str | None) -> str:
    """Return the namespace part of ``topic`` (a bag's absolute topic name), dot-joined.

    ``pattern`` is the relative ``--topic`` name it matched (its chunks are not namespace), or
    None for a topic taken by its type or named absolutely (then the last chunk is the name).
    """
    chunks = [c for c in topic.split("/") if c]
    tail = 1 if pattern is None or pattern.startswith("/") else len(pattern.strip("/").split("/"))
    return ".".join(chunks[: max(0, len(chunks) - tail)])


def matches(topic: str, pattern: str) -> bool:
    """Return whether a bag topic is the ``--topic`` name (relative: in any namespace)."""
    if pattern.startswith("/"):
        return topic.rstrip("/") == pattern.rstrip("/")
    return f"/{topic.strip('/')}".endswith(f"/{pattern.strip('/')}")


def import_bags(
    paths: Sequence[Path],
    out: Path,
    converter: Converter,
    *,
    topics: Sequence[str] = (),
    pose_topics: Sequence[str] = (),
    robot: str | None = None,
    root_robot: str = "robot",
    progress: Progress = NO_PROGRESS,
) -> ImportStats:
    """Write the frames of the landmark topics of ``paths`` (one bag or several) to ``out``.

    ``progress`` counts the messages read, of the chosen topics' total.

    Raises:
        ConfigError: no topic of the bags is a landmark topic (the message lists them), or a
            named topic is missing, or the bag cannot be read.
    """
    from rosbags.highlevel import AnyReader

    from lessmap_schemas.errors import InvalidNameError
    from lessmap_schemas.keys import validate_name

    stats = ImportStats()
    try:
        reader = AnyReader(list(paths), default_typestore=converter.store)
        reader.open()
    except Exception as exc:  # rosbags' reader errors have no common base with OSError
        msg = f"cannot read {', '.join(map(str, paths))}: {exc}"
        raise ConfigError(msg) from exc
    try:
        chosen = _choose(reader.connections, converter, topics, pose_topics)
        if not any(not pose for pose, _ in chosen.values()):
            listing = (
                ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections}))
                or "none"
            )
            msg = (
                f"no landmark topic in {', '.join(map(str, paths))} (topics: {listing}); "
                "name one with --topic, and for other types give --ids TYPE=PATH"
            )
            raise ConfigError(msg)
        for conn in reader.connections:
            if conn.topic in chosen:
                stats.topics[conn.topic] = conn.msgtype
        seqs: dict[str, int] = {}
        poses: dict[str, tuple[float, float, float]] = {}
        names: dict[str, str | None] = {}
        with out.open("w", encoding="utf-8") as sink:
            connections = [c for c in reader.connections if c.topic in chosen]
            total = sum(c.msgcount for c in connections)
            progress.stage(f"reading {len(connections)} topic(s)", total)
            messages = tracked(reader.messages(connections=connections), progress)
            for conn, timestamp_ns, raw in messages:
                converter.counts["received"] += 1
                is_pose, pattern = chosen[conn.topic]
                if conn.topic not in names:
                    name = robot or robot_of(conn.topic, pattern) or root_robot
                    try:
                        names[conn.topic] = validate_name(name, "robot")
                    except InvalidNameError as exc:
                        names[conn.topic] = None
                        converter.lost("bad robot name", f"{exc}; give one with --robot NAME")
                who = names[conn.topic]
                if who is None:
                    converter.counts["lost: bad robot name"] += 1
                    continue
                message = _deserialize(reader, converter, raw, conn.msgtype)
                if message is None:
                    continue
                if is_pose:
                    pose = converter.pose(conn.msgtype, message)
                    if pose is not None:
                        poses[who] = pose
                        converter.counts["poses"] += 1
                    continue
                features = converter.features(conn.msgtype, message)
                if features is None:
                    continue
                stamp = converter.stamp(message)
                row: dict[str, Any] = {
                    "robot": who,
                    "seq": seqs.get(who, 0),
                    "stamp": stamp if stamp is not None else timestamp_ns * 1e-9,
                    "features": features,
                }
                if who in poses:
                    row["pose"] = list(poses[who])
                sink.write(json.dumps(row, separators=(",", ":")) + "\n")
                seqs[who] = row["seq"] + 1
                converter.counts["frames"] += 1
        stats.frames = dict(sorted(seqs.items()))
    finally:
        reader.close()
    return stats


def _choose(
    connections: Sequence[Any],
    converter: Converter,
    topics: Sequence[str],
    pose_topics: Sequence[str],
) -> dict[str, tuple[bool, str | None]]:
    """Return the topics to read: topic -> (is a pose topic, the ``--topic`` it matched)."""
    chosen: dict[str, tuple[bool, str | None]] = {}
    for names, pose in ((topics, False), (pose_topics, True)):
        for pattern in names:
            found = [c for c in connections if matches(c.topic, pattern)]
            if not found:
                have = ", ".join(sorted({c.topic for c in connections})) or "none"
                msg = f"no topic {pattern!r} in the bag (topics: {have})"
                raise ConfigError(msg)
            for conn in found:
                wanted = converter.is_pose_type if pose else converter.is_landmark_type
                if not wanted(conn.msgtype):
                    kind = "pose" if pose else "landmark"
                    msg = f"{conn.topic} carries {conn.msgtype}, not a {kind} type" + (
                        "" if pose else "; give its IDs with --ids TYPE=PATH"
                    )
                    raise ConfigError(msg)
                chosen[conn.topic] = (pose, None if pattern.startswith("/") else pattern)
    if not topics:
        for conn in connections:
            # MarkerArray is too common (every RViz overlay) to be taken as landmarks unasked.
            if converter.is_landmark_type(conn.msgtype) and not conn.msgtype.startswith(
                "visualization_msgs/"
            ):
                chosen.setdefault(conn.topic, (False, None))
    return chosen


def _deserialize(
    reader: AnyReader, converter: Converter, raw: bytes, type_name: str
) -> object | None:
    try:
        return reader.deserialize(raw, type_name)
    except Exception as exc:  # rosbags raises several kinds for bytes that do not fit
        converter.lost(f"undecodable {type_name}", f"not this type ({exc})")
        return None

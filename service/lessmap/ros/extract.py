"""Which fields of a decoded ROS message are feature IDs, and where the robot is.

An *ID path* names the IDs inside a message, one step per field, ``[]`` to go through an
array, ``[field=value]`` to keep only its elements whose field has that value, and ``a+b`` at
the end to combine several fields of one element into one ID::

    detections[].id              apriltag_msgs/msg/AprilTagDetectionArray
    marker_ids[]                 ros2_aruco_interfaces/msg/ArucoMarkers
    markers[action=0].ns+id      visualization_msgs/msg/MarkerArray (ADD only)

A single non-negative integer is the feature ID itself; anything else (a string, a negative
number, a combination) is hashed to a stable 63-bit ID (the first 8 bytes of SHA-256 of its
JSON form), the same in every run, on every machine, live and offline.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, SupportsIndex, TypeGuard

from lessmap.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

#: The largest feature ID of the wire contract (a signed 64-bit integer).
MAX_FEATURE_ID = 2**63 - 1

#: The ID path of every type lessmap reads without being told.
DEFAULT_ID_PATHS: dict[str, str] = {
    "apriltag_msgs/msg/AprilTagDetectionArray": "detections[].id",
    "ros2_aruco_interfaces/msg/ArucoMarkers": "marker_ids[]",
    "visualization_msgs/msg/MarkerArray": "markers[action=0].ns+id",
}

#: Types that carry the robot's pose, and the path of their ``geometry_msgs/Pose``.
POSE_PATHS: dict[str, str] = {
    "nav_msgs/msg/Odometry": "pose.pose",
    "geometry_msgs/msg/PoseStamped": "pose",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "pose.pose",
}

_STEP = re.compile(
    r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*)"
    r"(?:\[(?:(?P<field>[A-Za-z_][A-Za-z0-9_]*)=(?P<value>[^\]]+))?\](?P<many>))?$"
)
_LEAF = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(?:\+[A-Za-z_][A-Za-z0-9_]*)*$")


@dataclass(frozen=True, slots=True)
class Step:
    """One field of an ID path; ``many`` when it is an array to go through."""

    name: str
    many: bool
    where: tuple[str, int | str] | None = None


@dataclass(frozen=True, slots=True)
class IdPath:
    """A parsed ID path: the steps down to the elements, then the fields making one ID."""

    text: str
    steps: tuple[Step, ...]
    leaf: tuple[str, ...]  # empty: the elements reached are the IDs themselves

    def ids(self, message: object) -> list[int]:
        """Return the feature IDs in ``message``, in message order, duplicates kept.

        Raises:
            ValueError: a field is missing or a value cannot be an ID.
        """
        found = []
        for element in _walk(message, self.steps):
            if self.leaf:
                values = [_field(element, name) for name in self.leaf]
                found.append(feature_id(values[0] if len(values) == 1 else values))
            else:
                found.append(feature_id(element))
        return found


def parse_id_path(text: str) -> IdPath:
    """Parse an ID path such as ``markers[action=0].ns+id``.

    Raises:
        ConfigError: the path is malformed (the message names the bad part).
    """
    parts = text.strip().split(".")
    steps: list[Step] = []
    leaf: tuple[str, ...] = ()
    for index, part in enumerate(parts):
        last = index == len(parts) - 1
        match = _STEP.match(part)
        if match is None:
            if last and _LEAF.match(part):
                leaf = tuple(part.split("+"))
                break
            msg = f"ID path {text!r}: cannot read {part!r} (e.g. detections[].id, markers[].ns+id)"
            raise ConfigError(msg)
        many = match.group("many") is not None
        where = None
        if match.group("field"):
            raw = match.group("value")
            where = (match.group("field"), int(raw) if re.fullmatch(r"-?\d+", raw) else raw)
        if last and not many:
            leaf = (match.group("name"),)
        else:
            steps.append(Step(match.group("name"), many, where))
    if not any(step.many for step in steps):
        msg = f"ID path {text!r} goes through no array: mark one with [] (e.g. marker_ids[])"
        raise ConfigError(msg)
    return IdPath(text.strip(), tuple(steps), leaf)


def parse_id_options(items: Sequence[str]) -> dict[str, IdPath]:
    """Parse ``TYPE=PATH`` options over the defaults: message type to ID path.

    Raises:
        ConfigError: an item is malformed.
    """
    from lessmap.ros.msgtypes import check_type_name

    paths = {name: parse_id_path(path) for name, path in DEFAULT_ID_PATHS.items()}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep:
            msg = f"--ids expects TYPE=PATH, got {item!r}"
            raise ConfigError(msg)
        paths[check_type_name(name.strip())] = parse_id_path(path)
    return paths


def feature_id(value: object) -> int:
    """Return the feature ID of one extracted value (see the module docstring).

    Raises:
        ValueError: the value is a float, a message or some other thing that is no ID.
    """
    if _is_int(value):
        number = int(value)
        if 0 <= number <= MAX_FEATURE_ID:
            return number
    canonical = _canonical(value)
    digest = hashlib.sha256(json.dumps(canonical, separators=(",", ":")).encode()).digest()
    return int.from_bytes(digest[:8], "big") >> 1


def pose_of(message: object, path: str) -> tuple[float, float, float] | None:
    """Return the planar pose (x_m, y_m, yaw_rad) of a ``geometry_msgs/Pose`` at ``path``.

    None when a value is not finite (a pose the wire contract would refuse).
    """
    pose: Any = message
    for name in path.split("."):
        pose = getattr(pose, name)
    q = pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    x, y = float(pose.position.x), float(pose.position.y)
    return (x, y, yaw) if all(map(math.isfinite, (x, y, yaw))) else None


def stamp_of(message: object) -> float | None:
    """Return ``header.stamp`` in seconds, or None without a header or with a zero stamp."""
    header = getattr(message, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    seconds = float(stamp.sec) + float(stamp.nanosec) * 1e-9
    return seconds if seconds > 0 else None


def _walk(value: object, steps: tuple[Step, ...]) -> Iterator[object]:
    if not steps:
        yield value
        return
    step, rest = steps[0], steps[1:]
    inner = _field(value, step.name)
    if not step.many:
        yield from _walk(inner, rest)
        return
    if isinstance(inner, str | bytes) or not hasattr(inner, "__iter__"):
        msg = f"field {step.name!r} is not an array"
        raise ValueError(msg)
    for element in inner:
        if step.where is not None:
            field, wanted = step.where
            if _plain(_field(element, field)) != wanted:
                continue
        yield from _walk(element, rest)


def _field(value: object, name: str) -> object:
    try:
        return getattr(value, name)
    except AttributeError:
        kind = getattr(value, "__msgtype__", type(value).__name__)
        msg = f"{kind} has no field {name!r}"
        raise ValueError(msg) from None


def _is_int(value: object) -> TypeGuard[SupportsIndex]:
    # numpy integers (rosbags decodes arrays of primitives as numpy arrays) have __index__.
    return not isinstance(value, bool | float) and hasattr(value, "__index__")


def _plain(value: object) -> object:
    return int(value) if _is_int(value) else value


def _canonical(value: object) -> object:
    if _is_int(value):
        return int(value)
    if isinstance(value, str):
        return value
    if isinstance(value, list | tuple):
        return [_canonical(v) for v in value]
    msg = f"{type(value).__name__} value {value!r:.40} is not a feature ID (an integer or string)"
    raise ValueError(msg)

"""The ROS message types lessmap reads, in a rosbags type store.

rosbags ships the standard ROS 2 interfaces (``visualization_msgs``, ``nav_msgs``,
``geometry_msgs`` ...) but not the detector packages: their definitions are registered here
from their ``.msg`` text, pinned to one release, because the RIHS01 type hash (the last chunk
of an rmw_zenoh key) and the CDR layout follow the text exactly. Users add their own with
``--msg-def TYPE=FILE.msg``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Mapping

    from rosbags.typesys.store import Typestore

#: apriltag_msgs 2.0.1 (christianrauch/apriltag_msgs, the package of ROS 2's apriltag_ros;
#: the 1.x releases had ``float64[2] centre`` and ``float64[8] corners`` instead of Point).
APRILTAG_MSGS = {
    "apriltag_msgs/msg/Point": "float64 x\nfloat64 y\n",
    "apriltag_msgs/msg/AprilTagDetection": (
        "string family\n"
        "int32 id\n"
        "int32 hamming\n"
        "float32 goodness\n"
        "float32 decision_margin\n"
        "Point centre\n"
        "Point[4] corners\n"
        "float64[9] homography\n"
    ),
    "apriltag_msgs/msg/AprilTagDetectionArray": (
        "std_msgs/Header header\nAprilTagDetection[] detections\n"
    ),
}

#: ros2_aruco_interfaces (JMU-ROBOTICS-VIVA/ros2_aruco).
ARUCO_MSGS = {
    "ros2_aruco_interfaces/msg/ArucoMarkers": (
        "std_msgs/Header header\nint64[] marker_ids\ngeometry_msgs/Pose[] poses\n"
    ),
}

#: Every definition lessmap registers beyond the type store's own, in registration order.
BUILTIN_DEFINITIONS: dict[str, str] = {**APRILTAG_MSGS, **ARUCO_MSGS}

_TYPE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*$")


def check_type_name(name: str) -> str:
    """Return ``name`` if it is a ROS message type name ``pkg/msg/Name``.

    Raises:
        ConfigError: it is not one.
    """
    if not _TYPE_NAME.match(name):
        msg = f"{name!r} is not a ROS message type name such as visualization_msgs/msg/MarkerArray"
        raise ConfigError(msg)
    return name


def dds_name(type_name: str) -> str:
    """Return the DDS name rmw_zenoh puts in its keys: ``pkg::msg::dds_::Name_``."""
    package, _, name = type_name.split("/")
    return f"{package}::msg::dds_::{name}_"


def ros_name(dds: str) -> str | None:
    """Return ``pkg/msg/Name`` for a DDS type name of an rmw_zenoh key, or None."""
    parts = dds.split("::")
    if len(parts) != 4 or parts[1:3] != ["msg", "dds_"] or not parts[3].endswith("_"):
        return None
    return f"{parts[0]}/msg/{parts[3][:-1]}"


def typestore(extra: Mapping[str, str] | None = None) -> Typestore:
    """Return a ROS 2 (Jazzy) type store with the detector types, lessmap_msgs and ``extra``.

    Args:
        extra: more definitions, type name to ``.msg`` text (a user's ``--msg-def``).

    Raises:
        ConfigError: a definition does not parse or names an unknown type.
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from lessmap.ros.outgoing import definitions

    store = get_typestore(Stores.ROS2_JAZZY)
    for name, text in {**BUILTIN_DEFINITIONS, **definitions(), **dict(extra or {})}.items():
        try:
            store.register(get_types_from_msg(text, check_type_name(name)))
        except ConfigError:
            raise
        except Exception as exc:  # rosbags raises several kinds for a bad definition
            msg = f"cannot register {name}: {exc}"
            raise ConfigError(msg) from exc
    return store


def read_definitions(items: list[str]) -> dict[str, str]:
    """Parse ``TYPE=FILE.msg`` options into type name to definition text.

    Raises:
        ConfigError: an item is not ``TYPE=FILE`` or names a bad type.
        FileNotFoundError: a file does not exist.
    """
    found: dict[str, str] = {}
    for item in items:
        name, sep, file = item.partition("=")
        if not sep or not file:
            msg = f"--msg-def expects TYPE=FILE.msg, got {item!r}"
            raise ConfigError(msg)
        try:
            found[check_type_name(name)] = Path(file).read_text(encoding="utf-8")
        except UnicodeDecodeError:
            msg = f"--msg-def {file}: not UTF-8 text"
            raise ConfigError(msg) from None
    return found

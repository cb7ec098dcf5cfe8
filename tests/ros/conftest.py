"""ROS messages built at run time: rosbags types registered from their ``.msg`` text."""

from __future__ import annotations

import math
import random
import struct
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="the [ros] extra is not installed")

from lessmap.ros.msgtypes import dds_name, typestore

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

APRILTAG = "apriltag_msgs/msg/AprilTagDetectionArray"
ARUCO = "ros2_aruco_interfaces/msg/ArucoMarkers"
MARKERS = "visualization_msgs/msg/MarkerArray"
ODOMETRY = "nav_msgs/msg/Odometry"


@pytest.fixture(scope="session")
def store() -> Typestore:
    return typestore()


def rooms_walk(rooms: int, frames_per_room: int, seed: int = 7) -> list[list[int]]:
    """Feature lists of a robot crossing ``rooms`` rooms of 8 tags each (ids 100*r + 1..8)."""
    rng = random.Random(seed)
    walk = []
    for room in range(rooms):
        tags = [100 * room + i for i in range(1, 9)]
        walk += [sorted(rng.sample(tags, 5)) for _ in range(frames_per_room)]
    return walk


def _header(store: Typestore, stamp_s: float) -> Any:
    time_type = store.types["builtin_interfaces/msg/Time"]
    sec = int(stamp_s)
    stamp = time_type(sec=sec, nanosec=round((stamp_s - sec) * 1e9))
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")


def apriltag_array(store: Typestore, ids: list[int], stamp_s: float) -> Any:
    point = store.types["apriltag_msgs/msg/Point"]
    detection = store.types["apriltag_msgs/msg/AprilTagDetection"]
    detections = [
        detection(
            family="36h11",
            id=tag,
            hamming=0,
            goodness=0.0,
            decision_margin=50.0,
            centre=point(x=320.0, y=240.0),
            corners=[point(x=float(i), y=float(i)) for i in range(4)],
            homography=np.zeros(9, dtype=np.float64),
        )
        for tag in ids
    ]
    return store.types[APRILTAG](header=_header(store, stamp_s), detections=detections)


def aruco_markers(store: Typestore, ids: list[int], stamp_s: float) -> Any:
    return store.types[ARUCO](
        header=_header(store, stamp_s),
        marker_ids=np.array(ids, dtype=np.int64),
        poses=[_pose(store, 0.0, 0.0, 0.0) for _ in ids],
    )


def marker_array(store: Typestore, items: list[tuple[str, int, int]], stamp_s: float) -> Any:
    """A MarkerArray of (ns, id, action) markers."""
    marker = store.types["visualization_msgs/msg/Marker"]
    color = store.types["std_msgs/msg/ColorRGBA"](r=1.0, g=0.0, b=0.0, a=1.0)
    vector = store.types["geometry_msgs/msg/Vector3"](x=0.1, y=0.1, z=0.1)
    duration = store.types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    markers = [
        marker(
            header=_header(store, stamp_s),
            ns=ns,
            id=ident,
            type=2,
            action=action,
            pose=_pose(store, 0.0, 0.0, 0.0),
            scale=vector,
            color=color,
            lifetime=duration,
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=store.types["sensor_msgs/msg/CompressedImage"](
                header=_header(store, stamp_s), format="", data=np.zeros(0, dtype=np.uint8)
            ),
            uv_coordinates=[],
            text="",
            mesh_resource="",
            mesh_file=store.types["visualization_msgs/msg/MeshFile"](
                filename="", data=np.zeros(0, dtype=np.uint8)
            ),
            mesh_use_embedded_materials=False,
        )
        for ns, ident, action in items
    ]
    return store.types[MARKERS](markers=markers)


def odometry(store: Typestore, x: float, y: float, yaw: float, stamp_s: float) -> Any:
    covariance = np.zeros(36, dtype=np.float64)
    pose = store.types["geometry_msgs/msg/PoseWithCovariance"](
        pose=_pose(store, x, y, yaw), covariance=covariance
    )
    vector = store.types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    twist = store.types["geometry_msgs/msg/TwistWithCovariance"](
        twist=store.types["geometry_msgs/msg/Twist"](linear=vector, angular=vector),
        covariance=covariance,
    )
    return store.types[ODOMETRY](
        header=_header(store, stamp_s), child_frame_id="base_link", pose=pose, twist=twist
    )


def _pose(store: Typestore, x: float, y: float, yaw: float) -> Any:
    point = store.types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0)
    quaternion = store.types["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
    )
    return store.types["geometry_msgs/msg/Pose"](position=point, orientation=quaternion)


def rmw_key(store: Typestore, domain: int, topic: str, type_name: str) -> str:
    """The Zenoh key rmw_zenoh publishes ``topic`` on."""
    return f"{domain}/{topic.strip('/')}/{dds_name(type_name)}/{store.hash_rihs01(type_name)}"


def rmw_attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """An attachment shaped as rmw_zenoh's: int64 sequence number, int64 source timestamp,
    the 16-byte source GID with its length (zenoh-ext serialization, little-endian)."""
    return struct.pack("<qq", seq, stamp_ns) + bytes([len(gid)]) + gid

"""The bridge in process: which keys it takes, which robot a key names, what it warns about."""

from __future__ import annotations

import json
from functools import partial
from typing import TYPE_CHECKING, Any

import pytest
import zenoh

from lessmap.ros.bags import matches, robot_of
from lessmap.ros.bridge import RosBridge, topic_specs
from lessmap.ros.convert import Converter
from lessmap.ros.extract import parse_id_options
from tests.conftest import wait_until
from tests.ros.conftest import APRILTAG, ARUCO, apriltag_array, aruco_markers, rmw_key

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from rosbags.typesys.store import Typestore


def test_topic_specs() -> None:
    specs = topic_specs(7, ["detections", "/amr1/cam/tags"], ["odom"], [APRILTAG])
    assert [(s.key, s.tail, s.pose) for s in specs] == [
        ("7/**/detections/*/*", 1, False),
        ("7/amr1/cam/tags/*/*", 1, False),
        ("7/**/odom/*/*", 1, True),
    ]
    (by_type,) = topic_specs(0, [], [], [APRILTAG])
    assert by_type.key == "0/**/apriltag_msgs::msg::dds_::AprilTagDetectionArray_/*"
    with pytest.raises(ValueError, match="not a ROS topic name"):
        topic_specs(0, ["a/**/b"], [], [])


def test_bag_topic_names() -> None:
    assert matches("/amr1/camera/detections", "camera/detections")
    assert not matches("/amr1/camera/detections", "detections2")
    assert matches("/amr1/detections", "/amr1/detections")
    assert robot_of("/amr1/camera/detections", "camera/detections") == "amr1"
    assert robot_of("/site/amr2/tags", None) == "site.amr2"
    assert robot_of("/tags", None) == ""


def matched(publisher: zenoh.Publisher) -> bool:
    status: Any = publisher.matching_status  # a MatchingStatus (the stubs say bool)
    return bool(status.matching)


@pytest.fixture
def sessions(router: str) -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    def open_client() -> zenoh.Session:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps("client"))
        conf.insert_json5("connect/endpoints", json.dumps([router]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("timestamping/enabled", "true")
        return zenoh.open(conf)

    with open_client() as ros, open_client() as bridge:
        yield ros, bridge


def test_every_detector_topic_by_type_with_namespaces_as_robots(
    sessions: tuple[zenoh.Session, zenoh.Session],
    store: Typestore,
    fleet_name: str,
    caplog: pytest.LogCaptureFixture,
) -> None:
    from lessmap_client.connection import Connection

    ros, bridge_session = sessions
    converter = Converter(store, parse_id_options([]))
    specs = topic_specs(0, [], [], [APRILTAG, ARUCO])
    with Connection.from_session(bridge_session) as conn:
        bridge = RosBridge(
            bridge_session, conn, fleet_name, converter, specs, wait_service_s=0
        ).start()
        try:
            publishers = {
                "amr5": (rmw_key(store, 0, "/amr5/detections", APRILTAG), APRILTAG),
                "site.amr6": (rmw_key(store, 0, "/site/amr6/aruco_markers", ARUCO), ARUCO),
                "robot": (rmw_key(store, 0, "/tags", APRILTAG), APRILTAG),  # root namespace
            }
            declared = {r: ros.declare_publisher(key) for r, (key, _) in publishers.items()}
            for robot, pub in declared.items():
                wait_until(partial(matched, pub), 20, f"the bridge to subscribe {robot}")
            for robot, pub in declared.items():
                kind = publishers[robot][1]
                make = apriltag_array if kind == APRILTAG else aruco_markers
                pub.put(bytes(store.serialize_cdr(make(store, [1, 2, 3], 5.0), kind)))
            # A sender with another definition of the type: named once in the log.
            other = rmw_key(store, 0, "/amr5/detections", APRILTAG).rsplit("/", 1)[0]
            message = apriltag_array(store, [4], 6.0)
            for _ in range(2):
                ros.put(f"{other}/RIHS01_{'0' * 64}", bytes(store.serialize_cdr(message, APRILTAG)))
            wait_until(lambda: converter.counts["frames"] == 5, 20, "five frames")
        finally:
            bridge.stop()
    assert bridge.robots() == sorted(publishers)
    warnings = [r.getMessage() for r in caplog.records if "type hash" in r.getMessage()]
    assert len(warnings) == 1
    assert APRILTAG in warnings[0]


def test_a_custom_type_from_its_msg_text_with_its_own_id_path(
    sessions: tuple[zenoh.Session, zenoh.Session], fleet_name: str, tmp_path: Path
) -> None:
    from lessmap.ros.extract import feature_id
    from lessmap.ros.msgtypes import read_definitions, typestore
    from lessmap_client.connection import Connection

    kind = "my_msgs/msg/Landmarks"
    definition = tmp_path / "Landmarks.msg"
    definition.write_text("std_msgs/Header header\nstring[] names\n")
    store = typestore(read_definitions([f"{kind}={definition}"]))
    converter = Converter(store, parse_id_options([f"{kind}=names[]"]), max_features=3)
    ros, bridge_session = sessions
    key = f"0/amr9/landmarks/my_msgs::msg::dds_::Landmarks_/{store.hash_rihs01(kind)}"
    header = apriltag_array(store, [], 9.0).header
    with Connection.from_session(bridge_session) as conn:
        specs = topic_specs(0, ["landmarks"], [], [])
        bridge = RosBridge(bridge_session, conn, fleet_name, converter, specs, wait_service_s=0)
        bridge.start()
        frames: list[bytes] = []
        sub = bridge_session.declare_subscriber(
            f"lessmap/v4/{fleet_name}/amr9/frames/*", lambda s: frames.append(s.payload.to_bytes())
        )
        try:
            pub = ros.declare_publisher(key)
            wait_until(partial(matched, pub), 20, "the bridge to subscribe")
            for names in (["door", "plant"], ["a", "b", "c", "d"]):  # the second: over the limit
                message = store.types[kind](header=header, names=names)
                pub.put(bytes(store.serialize_cdr(message, kind)))
            wait_until(lambda: converter.counts["received"] == 2, 20, "both messages")
            wait_until(lambda: len(frames) == 1, 20, "the frame")
        finally:
            sub.undeclare()
            bridge.stop()
    from lessmap_schemas.codec import decode
    from lessmap_schemas.messages import Frame

    frame = decode(frames[0], Frame)
    assert frame.features == [feature_id("door"), feature_id("plant")]
    assert frame.stamp_s == 9.0
    assert converter.counts["lost: over max_features_per_frame"] == 1

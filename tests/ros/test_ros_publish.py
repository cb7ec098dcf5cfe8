"""Transitions back out to ROS 2: what a ROS 2 node would receive, read off the bus.

A real Zenoh subscriber on loopback takes what lessmap puts on rmw_zenoh's data keys and
decodes it with rosbags; the liveliness tokens are parsed field by field against rmw_zenoh's
format (ros2/rmw_zenoh docs/design.md and liveliness_utils.cpp: ``@ros2_lv/<domain>/<zid>/
<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]``).
"""

from __future__ import annotations

import json
import math
import struct
import time
from importlib import resources
from typing import TYPE_CHECKING, Any, Literal

import pytest
import zenoh

from lessmap.ros import rmw
from lessmap.ros.outgoing import AREA_CHANGE, TRANSITION
from lessmap.ros.publisher import RosPublisher
from lessmap_schemas.messages import SubmapSummary, Transition
from tests.conftest import REPO, wait_until

if TYPE_CHECKING:
    from collections.abc import Iterator

    from rosbags.typesys.store import Typestore

DOMAIN = 3

#: rmw's QoS enum values a token may carry (rmw/types.h), by field of the QoS chunk.
RELIABILITY = {"", "0", "1", "2", "3", "4"}
DURABILITY = {"", "0", "1", "2", "3", "4"}
HISTORY = {"", "0", "1", "2", "3"}
LIVELINESS = {"", "0", "1", "3", "4", "5"}


def a_transition(
    robot: str, *, reason: Literal["SPECTRAL", "DISCONNECTED"] = "SPECTRAL"
) -> Transition:
    spectral = reason == "SPECTRAL"
    return Transition(
        fleet="warehouse",
        robot=robot,
        session="run-1",
        incarnation=7,
        seq=42,
        boundary_seq=38,
        stamp_s=1_700_000_000.25,
        reason=reason,
        ncut=0.125 if spectral else None,
        lambda2=0.03 if spectral else None,
        closed=SubmapSummary(id=0, first_seq=7, last_seq=41, frame_count=35, features=[1, 2, 3]),
        opened=SubmapSummary(id=1, first_seq=38, last_seq=42, frame_count=5, features=[3, 4]),
        boundary_features=[3],
        area=1,
        left_area=0,
        revisit=False,
        batch_frames=1,
        instance="demo",
        partition=23,
        epoch=2,
    )


@pytest.fixture
def sessions(router: str) -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """lessmap's session and a ROS node's, both clients of one router (as of rmw_zenohd)."""

    def open_client() -> zenoh.Session:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps("client"))
        conf.insert_json5("connect/endpoints", json.dumps([router]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        return zenoh.open(conf)

    with open_client() as ours, open_client() as theirs:
        yield ours, theirs


def parse_token(key: str) -> dict[str, str]:
    """Split a liveliness token into rmw_zenoh's named fields; fail on any other shape."""
    parts = key.split("/")
    names = ["admin", "domain", "zid", "nid", "id", "kind", "enclave", "namespace", "node"]
    topic = ["topic", "type", "hash", "qos"]
    assert len(parts) in (len(names), len(names) + len(topic)), key
    assert all(parts), f"an empty field in {key}"
    return dict(zip(names + topic, parts, strict=False))


def check_qos(chunk: str) -> None:
    """Parse a QoS chunk as rmw_zenoh's ``keyexpr_to_qos`` does."""
    fields = chunk.split(":")
    assert len(fields) == 6, chunk
    reliability, durability, history, deadline, lifespan, liveliness = fields
    assert reliability in RELIABILITY
    assert durability in DURABILITY
    kind, depth = history.split(",")
    assert kind in HISTORY
    assert depth == "" or depth.isdigit()
    for duration in (deadline, lifespan):
        assert all(p == "" or p.isdigit() for p in duration.split(",")), duration
        assert len(duration.split(",")) == 2
    policy, *lease = liveliness.split(",")
    assert policy in LIVELINESS
    assert len(lease) == 2
    assert all(p == "" or p.isdigit() for p in lease)


def test_rosbags_computes_the_type_hash_ros_2_does(store: Typestore) -> None:
    # ROS 2 Jazzy's hash of std_msgs/msg/String, as `ros2 topic info -v` prints it.
    ros_2 = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    assert store.hash_rihs01("std_msgs/msg/String") == ros_2
    for type_name in (TRANSITION, AREA_CHANGE):
        assert store.hash_rihs01(type_name).startswith("RIHS01_")


def test_the_shipped_ament_package_holds_the_registered_definitions() -> None:
    folder = resources.files("lessmap.ros").joinpath("lessmap_msgs")
    cmake = folder.joinpath("CMakeLists.txt").read_text(encoding="utf-8")
    package = folder.joinpath("package.xml").read_text(encoding="utf-8")
    for name in ("SubmapSummary", "Transition", "AreaChange"):
        assert f'"msg/{name}.msg"' in cmake
        assert folder.joinpath("msg", f"{name}.msg").is_file()
    version = (REPO / "VERSION").read_text(encoding="utf-8").strip()
    assert f"<version>{version}</version>" in package


def test_ros_namespaces_of_robot_names() -> None:
    assert rmw.ros_namespace("amr7", "robot") == "/amr7"
    assert rmw.ros_namespace("site.amr2", "robot") == "/site/amr2"
    assert rmw.ros_namespace("robot", "robot") == ""
    assert rmw.ros_namespace("amr-7", "robot") == "/amr_7"
    assert rmw.ros_namespace("7.a--b", "robot") == "/_7/a_b"


def test_transitions_reach_a_ros_2_subscriber_decoded_by_rosbags(
    sessions: tuple[zenoh.Session, zenoh.Session], store: Typestore
) -> None:
    ours, theirs = sessions
    received: list[tuple[str, bytes, bytes | None]] = []

    def on_sample(sample: zenoh.Sample) -> None:
        attachment = None if sample.attachment is None else sample.attachment.to_bytes()
        received.append((str(sample.key_expr), sample.payload.to_bytes(), attachment))

    data = theirs.declare_subscriber(f"{DOMAIN}/**", on_sample)
    tokens: list[str] = []
    alive = theirs.liveliness().declare_subscriber(
        f"{rmw.ADMIN_SPACE}/{DOMAIN}/**", lambda s: tokens.append(str(s.key_expr)), history=True
    )
    transitions_key = rmw.data_key(
        DOMAIN, "/amr1/lessmap/transitions", TRANSITION, store.hash_rihs01(TRANSITION)
    )
    probe = ours.declare_publisher(transitions_key)

    def matched() -> bool:
        status: Any = probe.matching_status  # a MatchingStatus (the stubs say bool)
        return bool(status.matching)

    wait_until(matched, 10, "the ROS side to subscribe")
    probe.undeclare()
    publisher = RosPublisher(
        ours, store, domain=DOMAIN, namespace_of=lambda r: rmw.ros_namespace(r, "robot")
    )
    try:
        sent = [a_transition("amr1"), a_transition("amr1", reason="DISCONNECTED")]
        before_ns = time.time_ns()
        for t in sent:
            publisher.publish(t)
        wait_until(lambda: len(received) == 4, 10, "two transitions and two area changes")
        # A token may arrive twice: from the subscriber's history and live.
        wait_until(lambda: len(set(tokens)) == 3, 10, "the node's and two publishers' tokens")
        published_tokens = publisher.tokens()
    finally:
        publisher.close()
        data.undeclare()
        alive.undeclare()

    by_key: dict[str, list[tuple[bytes, bytes | None]]] = {}
    for key, payload, attachment in received:
        by_key.setdefault(key, []).append((payload, attachment))
    area_key = rmw.data_key(
        DOMAIN, "/amr1/lessmap/area", AREA_CHANGE, store.hash_rihs01(AREA_CHANGE)
    )
    assert sorted(by_key) == sorted([transitions_key, area_key])
    assert transitions_key.startswith(
        f"{DOMAIN}/amr1/lessmap/transitions/lessmap_msgs::msg::dds_::"
    )

    for (payload, _), t in zip(by_key[transitions_key], sent, strict=True):
        msg: Any = store.deserialize_cdr(payload, TRANSITION)
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
        for field in ("fleet", "robot", "session", "seq", "boundary_seq", "reason", "area"):
            assert getattr(msg, field) == getattr(t, field), field
        for field in (
            "incarnation",
            "left_area",
            "revisit",
            "batch_frames",
            "instance",
            "partition",
            "epoch",
        ):
            assert getattr(msg, field) == getattr(t, field), field
        for name in ("ncut", "lambda2"):
            value = getattr(t, name)
            assert math.isnan(getattr(msg, name)) if value is None else getattr(msg, name) == value
        for side in ("closed", "opened"):
            ours_side, ros_side = getattr(t, side), getattr(msg, side)
            assert list(ros_side.features) == ours_side.features
            assert (ros_side.id, ros_side.first_seq, ros_side.last_seq, ros_side.frame_count) == (
                ours_side.id,
                ours_side.first_seq,
                ours_side.last_seq,
                ours_side.frame_count,
            )
        assert list(msg.boundary_features) == t.boundary_features
    area: Any = store.deserialize_cdr(by_key[area_key][0][0], AREA_CHANGE)
    assert (area.robot, area.seq, area.area, area.left_area, area.revisit) == (
        "amr1",
        42,
        1,
        0,
        False,
    )

    # The attachment, as rmw_zenoh's subscriptions read it: sequence number, source
    # timestamp (ns), then the 16-byte GID of the publisher's token with its length.
    (transitions_token,) = [k for k in published_tokens if "%transitions" in k]
    for n, (_, attachment) in enumerate(by_key[transitions_key]):
        assert attachment is not None
        assert len(attachment) == 8 + 8 + 1 + 16
        seq, stamp_ns, length = struct.unpack_from("<qqB", attachment)
        assert (seq, length) == (n, 16)
        assert before_ns <= stamp_ns <= time.time_ns()
        assert attachment[17:] == rmw.gid_of(transitions_token)

    # The tokens: what rmw_zenoh's graph cache parses to list the node and its topics.
    assert sorted(set(tokens)) == sorted(published_tokens)
    fields = [parse_token(k) for k in set(tokens)]
    zid = str(ours.zid())
    for f in fields:
        assert (f["admin"], f["domain"], f["zid"], f["enclave"]) == ("@ros2_lv", "3", zid, "%")
        assert f["nid"].isdigit()
        assert f["id"].isdigit()
        assert f["namespace"] == "%"
        assert f["node"] == "lessmap"
    (node,) = [f for f in fields if f["kind"] == "NN"]
    assert node["nid"] == node["id"]
    assert "topic" not in node
    publishers = {f["topic"]: f for f in fields if f["kind"] == "MP"}
    assert sorted(publishers) == ["%amr1%lessmap%area", "%amr1%lessmap%transitions"]
    assert len({f["id"] for f in fields}) == 3  # one entity id each
    for topic, type_name in (("transitions", TRANSITION), ("area", AREA_CHANGE)):
        f = publishers[f"%amr1%lessmap%{topic}"]
        assert f["nid"] == node["nid"]
        assert f["type"] == f"lessmap_msgs::msg::dds_::{type_name.rsplit('/', 1)[1]}_"
        assert f["hash"] == store.hash_rihs01(type_name)
        check_qos(f["qos"])
        reliability, durability, history = f["qos"].split(":")[:3]
        assert (reliability, durability, history) == ("", "2", ",10")  # reliable, volatile

"""``lessmap ros`` end to end: rmw_zenoh-shaped CDR messages in, frames and transitions out.

A real ``lessmap serve``, a real ``lessmap ros`` process joined to its router, and a test
session that publishes exactly what an rmw_zenoh node puts on Zenoh: CDR payloads on
``<domain>/<topic>/<DDS type>/<RIHS01 hash>`` with an rmw_zenoh-shaped attachment.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.ros.extract import feature_id
from tests.conftest import wait_until
from tests.ros.conftest import (
    APRILTAG,
    ARUCO,
    MARKERS,
    ODOMETRY,
    apriltag_array,
    aruco_markers,
    marker_array,
    odometry,
    rmw_attachment,
    rmw_key,
    rooms_walk,
)

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import zenoh
    from rosbags.typesys.store import Typestore

    from tests.conftest import ServeProcess

FRAMES_PER_ROOM = 15


def start_bridge(endpoint: str, fleet: str, tmp_path: Path, *extra: str) -> subprocess.Popen[str]:
    with (tmp_path / "ros.log").open("w") as log:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "lessmap",
                "-v",
                "ros",
                "-e",
                endpoint,
                "--fleet",
                fleet,
                *extra,
            ],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
            env={**os.environ, "ROS_DOMAIN_ID": "3"},
        )


def stop_bridge(bridge: subprocess.Popen[str]) -> dict[str, object]:
    bridge.send_signal(signal.SIGTERM)
    try:
        out, _ = bridge.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        bridge.kill()
        bridge.wait(5)
        raise
    assert bridge.returncode == 0
    summary: dict[str, object] = json.loads(out.strip().splitlines()[-1])
    return summary


def wait_matched(publisher: zenoh.Publisher, what: str) -> None:
    def matched() -> bool:
        status: Any = publisher.matching_status  # a MatchingStatus (the stubs say bool)
        return bool(status.matching)

    wait_until(matched, 30.0, f"the bridge to subscribe {what}")


def test_rmw_zenoh_topics_become_frames_and_transitions(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    store: Typestore,
    tmp_path: Path,
) -> None:
    import lessmap_client
    from lessmap_schemas import keys
    from lessmap_schemas.codec import decode
    from lessmap_schemas.messages import Frame, Transition

    service = serve("--memory-only", "--max-batch-frames", "1")
    bridge = start_bridge(
        service.endpoint,
        fleet_name,
        tmp_path,
        *("--topic", "detections", "--topic", "aruco_markers", "--topic", "markers"),
        *("--pose-topic", "odom"),
    )
    try:
        with lessmap_client.connect(service.endpoint, timeout_s=20) as conn:
            assert conn.wait_for_service(20)
            transitions = conn.subscribe_transitions(fleet_name)
            session = client_session(service.endpoint)
            frames_seen: list[Frame] = []
            frames_sub = session.declare_subscriber(
                f"{keys.KEY_PREFIX}/{fleet_name}/amr1/frames/*",
                lambda s: frames_seen.append(decode(s.payload.to_bytes(), Frame)),
            )
            # amr1: AprilTag detections and odometry in namespace /amr1; amr2: ArUco
            # markers in /site/amr2; amr3: a MarkerArray with DELETEALL entries to skip.
            pubs = {
                "tags": session.declare_publisher(rmw_key(store, 3, "/amr1/detections", APRILTAG)),
                "odom": session.declare_publisher(rmw_key(store, 3, "/amr1/odom", ODOMETRY)),
                "aruco": session.declare_publisher(
                    rmw_key(store, 3, "/site/amr2/aruco_markers", ARUCO)
                ),
                "markers": session.declare_publisher(rmw_key(store, 3, "/amr3/markers", MARKERS)),
            }
            other_domain = session.declare_publisher(
                rmw_key(store, 0, "/amr1/detections", APRILTAG)
            )
            for name, pub in pubs.items():
                wait_matched(pub, name)
            walk = rooms_walk(2, FRAMES_PER_ROOM)
            gid = bytes(range(16))
            for seq, ids in enumerate(walk):
                stamp = 1000.0 + 0.1 * seq
                attachment = rmw_attachment(seq, int(stamp * 1e9), gid)
                odom = odometry(store, 0.1 * seq, 0.0, 0.0, stamp)
                pubs["odom"].put(bytes(store.serialize_cdr(odom, ODOMETRY)), attachment=attachment)
                time.sleep(0.005)  # paced like a sensor: odometry a moment before the camera
                tags = apriltag_array(store, ids, stamp)
                pubs["tags"].put(bytes(store.serialize_cdr(tags, APRILTAG)), attachment=attachment)
                aruco = aruco_markers(store, ids, stamp)
                pubs["aruco"].put(bytes(store.serialize_cdr(aruco, ARUCO)), attachment=attachment)
                items = [("landmarks", i, 0) for i in ids] + [("", 0, 3)]
                markers = marker_array(store, items, stamp)
                pubs["markers"].put(bytes(store.serialize_cdr(markers, MARKERS)))
            # Not lessmap's domain: ignored. Garbage and an empty detection: counted.
            other_domain.put(bytes(store.serialize_cdr(apriltag_array(store, [1], 1.0), APRILTAG)))
            pubs["tags"].put(b"\x00\x01 not CDR")
            empty = apriltag_array(store, [], 2000.0)
            pubs["tags"].put(bytes(store.serialize_cdr(empty, APRILTAG)))

            robots = ("amr1", "site.amr2", "amr3")

            def all_applied() -> bool:
                states = {s.robot: s for s in conn.states(fleet_name)}
                return all(r in states and states[r].frames_applied == len(walk) for r in robots)

            wait_until(all_applied, 30.0, "every robot's frames to be applied")
            got: dict[str, list[Transition]] = {}
            deadline = time.monotonic() + 20
            while {r for r in robots if got.get(r)} != set(robots):
                assert time.monotonic() < deadline, f"transitions of {sorted(got)} only"
                t = transitions.recv(0.5)
                if t is not None:
                    got.setdefault(t.robot, []).append(t)
            frames_sub.undeclare()
    finally:
        summary = stop_bridge(bridge)

    room_a = {i for ids in walk[:FRAMES_PER_ROOM] for i in ids}
    for robot in ("amr1", "site.amr2"):
        (first, *_) = got[robot]
        assert first.seq == FRAMES_PER_ROOM  # the first frame in the second room
        assert set(first.closed.features) == room_a  # tag and marker IDs are the features
    (first,) = got["amr3"][:1]
    assert set(first.closed.features) == {feature_id(["landmarks", i]) for i in room_a}
    assert feature_id(["", 0]) not in first.closed.features  # DELETEALL is no landmark
    # The latest odometry pose travels with each frame of amr1.
    assert frames_seen, "no frame of amr1 seen"
    # Paired by stamp: the odometry of the frame's instant, or the nearest one received when
    # that one was still in transit (Zenoh keeps the order of each key, not across keys, and
    # on a loaded machine odometry fell 4 messages behind the detections): always a pose the
    # robot really sent, never one from after the next frame.
    # A frame goes without a pose only until the first odometry has reached the bridge (under
    # load that can take a few frames): once a pose is known, every frame carries one.
    posed = [f for f in frames_seen if f.pose is not None]
    assert posed, "no frame of amr1 carried a pose"
    unposed = [f.seq for f in frames_seen if f.pose is None]
    assert all(seq < min(f.seq for f in posed) for seq in unposed), unposed
    exact = 0
    for frame in posed:
        assert frame.pose is not None
        sent = [pytest.approx((0.1 * k, 0.0, 0.0)) for k in range(frame.seq + 2)]
        assert frame.pose in sent, (frame.seq, frame.pose)
        exact += frame.pose == pytest.approx((0.1 * frame.seq, 0.0, 0.0))
    assert exact > 0, "no frame carried the odometry of its own instant"
    assert frames_seen[0].stamp_s == pytest.approx(1000.0)  # the header's stamp
    assert summary["robots"] == sorted(robots)
    assert summary["frames"] == 3 * len(walk)
    assert summary["poses"] == len(walk)
    assert summary["empty"] == 1
    assert summary[f"lost: undecodable {APRILTAG}"] == 1
    assert not [k for k in summary if k.startswith("lost:") and "undecodable" not in k]


def test_lessmap_ros_publishes_the_transitions_back_to_ros_2(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    store: Typestore,
    tmp_path: Path,
) -> None:
    import lessmap_client
    from lessmap.ros.outgoing import TRANSITION

    service = serve("--memory-only", "--max-batch-frames", "1")
    ros_node = client_session(service.endpoint)
    from_lessmap: list[bytes] = []
    ros_sub = ros_node.declare_subscriber(
        f"3/amr1/lessmap/transitions/lessmap_msgs::msg::dds_::Transition_/{store.hash_rihs01(TRANSITION)}",
        lambda s: from_lessmap.append(s.payload.to_bytes()),
    )
    bridge = start_bridge(service.endpoint, fleet_name, tmp_path, "--topic", "detections")
    try:
        with lessmap_client.connect(service.endpoint, timeout_s=20) as conn:
            assert conn.wait_for_service(20)
            transitions = conn.subscribe_transitions(fleet_name)
            tags = ros_node.declare_publisher(rmw_key(store, 3, "/amr1/detections", APRILTAG))
            wait_matched(tags, "detections")
            # The bridge's own subscription to the fleet's transitions, before the walk.
            wait_until(
                lambda: "ROS 2 publisher ready" in (tmp_path / "ros.log").read_text(),
                20,
                "the bridge to follow transitions",
            )
            for seq, ids in enumerate(rooms_walk(2, FRAMES_PER_ROOM)):
                message = apriltag_array(store, ids, 1000.0 + 0.1 * seq)
                tags.put(
                    bytes(store.serialize_cdr(message, APRILTAG)),
                    attachment=rmw_attachment(seq, int((1000.0 + 0.1 * seq) * 1e9), bytes(16)),
                )
            first = transitions.recv(30)
            assert first is not None, "no transition from lessmap"
            wait_until(lambda: bool(from_lessmap), 20, "the transition on the ROS 2 topic")
    finally:
        summary = stop_bridge(bridge)
        ros_sub.undeclare()
    echoed: Any = store.deserialize_cdr(from_lessmap[0], TRANSITION)
    assert (echoed.fleet, echoed.robot, echoed.seq, echoed.area) == (
        first.fleet,
        first.robot,
        first.seq,
        first.area,
    )
    assert list(echoed.closed.features) == first.closed.features
    published = summary["published to ROS"]
    assert isinstance(published, int)
    assert published >= 1

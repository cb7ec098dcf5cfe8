"""``lessmap import``: bags written here with rosbags come back as the frames put in them."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.cli.app import main
from lessmap.ros.extract import feature_id
from tests.ros.conftest import (
    APRILTAG,
    ARUCO,
    MARKERS,
    ODOMETRY,
    apriltag_array,
    aruco_markers,
    marker_array,
    odometry,
    rooms_walk,
)

if TYPE_CHECKING:
    from pathlib import Path

    from rosbags.typesys.store import Typestore

FRAMES_PER_ROOM = 15
WALK = rooms_walk(2, FRAMES_PER_ROOM)


def stamp_of(seq: int) -> float:
    return 1700000000.0 + 0.25 * seq


def write_rosbag2(path: Path, store: Typestore, storage: str) -> None:
    """amr1: AprilTag + odometry; site/amr2: ArUco; amr3: MarkerArray; plus a camera topic."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {
            topic: writer.add_connection(topic, kind, typestore=store)
            for topic, kind in (
                ("/amr1/detections", APRILTAG),
                ("/amr1/odom", ODOMETRY),
                ("/site/amr2/aruco_markers", ARUCO),
                ("/amr3/markers", MARKERS),
                ("/amr1/camera/info", "std_msgs/msg/String"),
            )
        }
        for seq, ids in enumerate(WALK):
            stamp = stamp_of(seq)
            ns = int(stamp * 1e9)
            messages = [
                ("/amr1/odom", odometry(store, 0.5 * seq, 1.0, 0.25, stamp), ODOMETRY),
                ("/amr1/detections", apriltag_array(store, ids, stamp), APRILTAG),
                ("/site/amr2/aruco_markers", aruco_markers(store, ids, stamp), ARUCO),
                (
                    "/amr3/markers",
                    marker_array(store, [("tags", i, 0) for i in ids], stamp),
                    MARKERS,
                ),
            ]
            for offset, (topic, message, kind) in enumerate(messages):
                writer.write(conns[topic], ns + offset, bytes(store.serialize_cdr(message, kind)))
        string = store.types["std_msgs/msg/String"](data="not landmarks")
        writer.write(
            conns["/amr1/camera/info"],
            ns + 9,
            bytes(store.serialize_cdr(string, "std_msgs/msg/String")),
        )


def read_frames(path: Path) -> dict[str, list[dict[str, Any]]]:
    rows: dict[str, list[dict[str, Any]]] = {}
    for line in path.read_text().splitlines():
        row = json.loads(line)
        rows.setdefault(row["robot"], []).append(row)
    return rows


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, dict[str, Any]]:
    code = main(argv)
    out = capsys.readouterr().out.strip().splitlines()
    return code, json.loads(out[-1]) if out else {}


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_rosbag2_round_trip(
    storage: str, store: Typestore, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / f"run-{storage}"
    write_rosbag2(bag, store, storage)
    out = tmp_path / "run.frames.jsonl"
    argv = ["import", str(bag), "--out", str(out), "--topic", "detections"]
    argv += ["--topic", "aruco_markers", "--topic", "markers", "--pose-topic", "odom"]
    code, summary = run_cli(argv, capsys)
    assert code == 0
    frames = read_frames(out)
    assert sorted(frames) == ["amr1", "amr3", "site.amr2"]
    for robot, rows in frames.items():
        assert [r["seq"] for r in rows] == list(range(len(WALK)))
        assert [r["stamp"] for r in rows] == pytest.approx([stamp_of(s) for s in range(len(WALK))])
        if robot == "amr3":
            assert [r["features"] for r in rows] == [
                [feature_id(["tags", i]) for i in ids] for ids in WALK
            ]
        else:
            assert [r["features"] for r in rows] == WALK
    for seq, row in enumerate(frames["amr1"]):
        assert row["pose"] == pytest.approx([0.5 * seq, 1.0, 0.25])
    assert "pose" not in frames["site.amr2"][0]  # no pose topic in that namespace
    assert summary["robots"] == {"amr1": len(WALK), "amr3": len(WALK), "site.amr2": len(WALK)}
    assert summary["frames"] == 3 * len(WALK)
    assert not [k for k in summary if k.startswith("lost:")]
    assert "/amr1/camera/info" not in summary["topics"]

    # The frames file is what every offline tool reads: one transition per robot, at the door.
    assert main(["segment", str(out), "--summary-only"]) == 0
    assert main(["segment", str(out)]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    transitions = [line for line in lines if "closed" in line]
    assert sorted(t["robot"] for t in transitions) == ["amr1", "amr3", "site.amr2"]
    assert {t["seq"] for t in transitions} == {FRAMES_PER_ROOM}


def test_default_topics_are_the_detector_types(
    store: Typestore, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "bag"
    write_rosbag2(bag, store, "mcap")
    out = tmp_path / "out.frames.jsonl"
    code, summary = run_cli(["import", str(bag), "--out", str(out)], capsys)
    assert code == 0
    assert summary["topics"] == {"/amr1/detections": APRILTAG, "/site/amr2/aruco_markers": ARUCO}


def test_ros1_bag_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ros1 = get_typestore(Stores.ROS1_NOETIC)
    t = ros1.types
    bag = tmp_path / "run.bag"

    def header(seq: int) -> Any:
        stamp = stamp_of(seq)
        sec = int(stamp)
        time = t["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((stamp - sec) * 1e9))
        return t["std_msgs/msg/Header"](seq=seq, stamp=time, frame_id="map")

    def pose() -> Any:
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )

    vector = t["geometry_msgs/msg/Vector3"](x=0.1, y=0.1, z=0.1)
    color = t["std_msgs/msg/ColorRGBA"](r=1.0, g=1.0, b=1.0, a=1.0)
    with Writer(bag) as writer:
        conn = writer.add_connection("/amr4/landmarks", MARKERS, typestore=ros1)
        for seq, ids in enumerate(WALK):
            markers = [
                t["visualization_msgs/msg/Marker"](
                    header=header(seq),
                    ns="beacons",
                    id=i,
                    type=2,
                    action=0,
                    pose=pose(),
                    scale=vector,
                    color=color,
                    lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
                    frame_locked=False,
                    points=[],
                    colors=[],
                    text="",
                    mesh_resource="",
                    mesh_use_embedded_materials=False,
                )
                for i in ids
            ]
            message = t[MARKERS](markers=markers)
            data = ros1.serialize_ros1(message, MARKERS)
            writer.write(conn, int(stamp_of(seq) * 1e9), bytes(np.asarray(data)))
    out = tmp_path / "ros1.frames.jsonl"
    code, summary = run_cli(["import", str(bag), "--topic", "landmarks", "--out", str(out)], capsys)
    assert code == 0
    rows = read_frames(out)["amr4"]
    assert [r["features"] for r in rows] == [
        [feature_id(["beacons", i]) for i in ids] for ids in WALK
    ]
    assert [r["stamp"] for r in rows] == pytest.approx([stamp_of(s) for s in range(len(WALK))])
    assert summary["robots"] == {"amr4": len(WALK)}


def test_a_bag_without_landmarks_lists_its_topics(
    store: Typestore, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from rosbags.rosbag2 import Writer

    bag = tmp_path / "empty"
    with Writer(bag, version=9) as writer:
        conn = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        message = store.types["std_msgs/msg/String"](data="hello")
        writer.write(conn, 1, bytes(store.serialize_cdr(message, "std_msgs/msg/String")))
    assert main(["import", str(bag), "--out", str(tmp_path / "x.jsonl")]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    assert err.startswith(f"lessmap import: no landmark topic in {bag}")
    assert "/chatter (std_msgs/msg/String)" in err
    assert main(["import", str(bag), "--topic", "chatter"]) == 1
    assert "give its IDs with --ids TYPE=PATH" in capsys.readouterr().err
    assert main(["import", str(tmp_path / "missing"), "--out", str(tmp_path / "x.jsonl")]) == 1
    assert (
        capsys.readouterr().err
        == f"lessmap import: {tmp_path / 'missing'}: no such file or folder\n"
    )

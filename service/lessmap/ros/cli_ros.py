"""``lessmap ros`` (live, from rmw_zenoh) and ``lessmap import`` (offline, from bags).

No ROS installation is needed: the bridge is a Zenoh client of the ROS 2 router
(``rmw_zenohd``); both decode with rosbags (the ``lessmap[ros]`` extra).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap.cli.foreground import StopSignal, add_run_options, stop_signals
from lessmap.errors import ConfigError
from lessmap_client.cli_options import add_zenoh_options, positive_int, zenoh_options

if TYPE_CHECKING:
    import zenoh

    from lessmap.ros.bridge import RosBridge
    from lessmap.ros.convert import Converter
    from lessmap.ros.publisher import RosPublisher
    from lessmap_client.connection import Connection
    from lessmap_client.subscription import Subscription
    from lessmap_schemas.messages import Transition

log = logging.getLogger(__name__)

#: What to check when the ROS 2 router does not answer.
ROS_ROUTER_HINT = "is rmw_zenohd running there? (ros2 run rmw_zenoh_cpp rmw_zenohd)"


def add_message_options(parser: argparse.ArgumentParser) -> None:
    """Options shared with ``lessmap import``: ID paths and extra message definitions."""
    parser.add_argument(
        "--ids",
        action="append",
        default=[],
        metavar="TYPE=PATH",
        help="where a message type's feature IDs are, e.g. "
        "'vision_msgs/msg/Detection2DArray=detections[].results[].hypothesis.class_id' "
        "(repeatable; built in: AprilTagDetectionArray detections[].id, ArucoMarkers "
        "marker_ids[], MarkerArray markers[action=0].ns+id)",
    )
    parser.add_argument(
        "--msg-def",
        action="append",
        default=[],
        metavar="TYPE=FILE.msg",
        help="register a message type from its .msg text (repeatable; define nested types first)",
    )
    parser.add_argument(
        "--max-features-per-frame",
        type=positive_int,
        default=4096,
        metavar="N",
        help="the service's limit: a message with more features is counted and skipped",
    )


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap ros``."""
    parser.description = (
        "Bridge ROS 2 landmark detections to lessmap, live: subscribe to rmw_zenoh topics "
        "(AprilTag detections, ArUco markers, MarkerArray, or any type given --ids) and "
        "publish one lessmap frame per message, one robot per ROS namespace. -e/--connect "
        "names the ROS 2 router (rmw_zenohd). Needs pip install 'lessmap[ros]'; no ROS "
        "installation."
    )
    add_zenoh_options(parser)
    parser.add_argument(
        "--lessmap-connect",
        action="append",
        metavar="ENDPOINT",
        help="the lessmap router, when it is not the ROS 2 one (default: the same session)",
    )
    parser.add_argument("--fleet", default="ros", help="fleet of the robots (default ros)")
    parser.add_argument(
        "--domain",
        type=int,
        default=None,
        help="ROS domain id (default: $ROS_DOMAIN_ID, else 0)",
    )
    parser.add_argument(
        "--topic",
        action="append",
        default=[],
        metavar="NAME",
        help="a landmark topic: relative (detections: in every namespace) or absolute "
        "(/amr7/detections); repeatable. Default: every topic of type AprilTagDetectionArray "
        "or ArucoMarkers",
    )
    parser.add_argument(
        "--pose-topic",
        action="append",
        default=[],
        metavar="NAME",
        help="a topic with the robot's pose (nav_msgs/Odometry, PoseStamped, "
        "PoseWithCovarianceStamped), e.g. odom; the pose nearest in time goes with each frame",
    )
    parser.add_argument(
        "--robot",
        help="one robot name for every message (default: the topic's ROS namespace)",
    )
    parser.add_argument(
        "--root-robot",
        default="robot",
        help="robot name of topics in the root namespace (default robot)",
    )
    parser.add_argument(
        "--publish-ros",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="publish the robots' transitions back to ROS 2, as lessmap_msgs/msg/Transition on "
        "<namespace>/lessmap/transitions and lessmap_msgs/msg/AreaChange on "
        "<namespace>/lessmap/area (default: on)",
    )
    add_message_options(parser)
    add_run_options(parser)


def converter_from_args(args: argparse.Namespace) -> Converter:
    """Build the ``Converter`` of ``--ids``, ``--msg-def`` and the feature limit."""
    from lessmap.ros.convert import Converter
    from lessmap.ros.extract import parse_id_options
    from lessmap.ros.msgtypes import read_definitions, typestore

    id_paths = parse_id_options(args.ids)
    store = typestore(read_definitions(args.msg_def))
    return Converter(store, id_paths, max_features=args.max_features_per_frame)


def run(args: argparse.Namespace) -> int:
    """Run the bridge until a signal or ``--duration``; print its counts as JSON."""
    with stop_signals() as stop:
        return _run(args, stop)


def _run(args: argparse.Namespace, stop: StopSignal) -> int:
    import zenoh

    from lessmap.ros.bridge import RosBridge, topic_specs
    from lessmap_client.connection import Connection

    converter = converter_from_args(args)
    domain = args.domain if args.domain is not None else _env_domain()
    try:
        specs = topic_specs(domain, args.topic, args.pose_topic, sorted(converter.id_paths))
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
    if not args.topic:
        # MarkerArray is too common (every RViz overlay) to be taken as landmarks unasked.
        specs = [s for s in specs if "visualization_msgs" not in s.key]
    zenoh.init_log_from_env_or("error")
    net = zenoh_options(args)
    ros_session = net.open_session(hint=ROS_ROUTER_HINT)
    lessmap_session = ros_session
    try:
        if args.lessmap_connect:
            lessmap = replace(net, connect=tuple(args.lessmap_connect), listen=())
            lessmap_session = lessmap.open_session()
        with Connection.from_session(lessmap_session) as conn:
            bridge = RosBridge(
                ros_session,
                conn,
                args.fleet,
                converter,
                specs,
                robot=args.robot,
                root_robot=args.root_robot,
            ).start()
            outbound = _publish_back(args, ros_session, conn, bridge, converter, domain)
            try:
                stop.wait(args.duration)
            finally:
                if outbound is not None:
                    outbound[0].close()  # the subscription first: the publisher's one caller
                    outbound[1].close()
                bridge.stop()
            summary = {
                "fleet": bridge.fleet,
                "robots": bridge.robots(),
                **dict(sorted(converter.counts.items())),
            }
            if outbound is not None:
                summary["published to ROS"] = outbound[1].published
    finally:
        if lessmap_session is not ros_session:
            lessmap_session.close()
        ros_session.close()
    print(json.dumps(summary))
    return 0


def _publish_back(
    args: argparse.Namespace,
    ros_session: zenoh.Session,
    conn: Connection,
    bridge: RosBridge,
    converter: Converter,
    domain: int,
) -> tuple[Subscription[Transition], RosPublisher] | None:
    """Follow the fleet's transitions and publish each to ROS 2 (``--publish-ros``)."""
    if not args.publish_ros:
        return None
    from lessmap.ros.publisher import RosPublisher

    publisher = RosPublisher(
        ros_session, converter.store, domain=domain, namespace_of=bridge.namespace_of
    )
    try:
        # Live only: a restarted bridge must not publish old transitions again.
        sub = conn.subscribe_transitions(bridge.fleet, history=False, handler=publisher.publish)
    except BaseException:
        publisher.close()
        raise
    log.info(
        "ROS 2 publisher ready: fleet %s's transitions go to <namespace>/lessmap/transitions "
        "and <namespace>/lessmap/area, domain %d",
        bridge.fleet,
        domain,
    )
    return sub, publisher


def _env_domain() -> int:
    raw = os.environ.get("ROS_DOMAIN_ID", "0").strip() or "0"
    if not raw.isdigit() or int(raw) > 232:
        msg = f"ROS_DOMAIN_ID={raw!r} is not a ROS domain id (0-232)"
        raise ConfigError(msg)
    return int(raw)


def configure_import(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap import``."""
    parser.description = (
        "Convert the landmark topics of a rosbag2 (sqlite3 or MCAP folder or file) or ROS 1 "
        "bag to a frames file (one frame per message, one robot per ROS namespace), for "
        "lessmap segment, eval, plot and replay. Needs pip install 'lessmap[ros]'."
    )
    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="bag(s) to read")
    parser.add_argument(
        "-o",
        "--out",
        type=Path,
        default=None,
        metavar="FILE",
        help="frames file to write (default: BAG's name + .frames.jsonl, here)",
    )
    parser.add_argument(
        "--topic",
        action="append",
        default=[],
        metavar="NAME",
        help="a landmark topic: relative (detections: in every namespace) or absolute; "
        "repeatable. Default: every AprilTagDetectionArray and ArucoMarkers topic",
    )
    parser.add_argument(
        "--pose-topic",
        action="append",
        default=[],
        metavar="NAME",
        help="a topic with the robot's pose (Odometry, PoseStamped, "
        "PoseWithCovarianceStamped); the latest pose before each frame goes with it",
    )
    parser.add_argument("--robot", help="one robot name for every frame (default: namespace)")
    parser.add_argument(
        "--root-robot",
        default="robot",
        help="robot name of topics in the root namespace (default robot)",
    )
    add_message_options(parser)


def run_import(args: argparse.Namespace) -> int:
    """Write the frames file; print what was written as JSON."""
    from lessmap.cli.progress import progress
    from lessmap.ros.bags import import_bags

    converter = converter_from_args(args)
    missing = [str(bag) for bag in args.bags if not bag.exists()]
    if missing:
        msg = f"{', '.join(missing)}: no such file or folder"
        raise ConfigError(msg)
    first: Path = args.bags[0]
    out: Path = args.out or Path(f"{first.stem or first.name}.frames.jsonl")
    if not out.resolve().parent.is_dir():  # before reading the bags, not after
        msg = f"-o/--out {out}: no folder {out.parent}"
        raise ConfigError(msg)
    with progress(args) as shown:
        stats = import_bags(
            args.bags,
            out,
            converter,
            topics=args.topic,
            pose_topics=args.pose_topic,
            robot=args.robot,
            root_robot=args.root_robot,
            progress=shown,
        )
    summary = {
        "out": str(out),
        "robots": stats.frames,
        "topics": stats.topics,
        **dict(sorted(converter.counts.items())),
    }
    print(json.dumps(summary))
    return 0

"""Live ROS 2 input: landmark detections on rmw_zenoh topics become lessmap frames.

rmw_zenoh puts every message of a topic on the Zenoh key
``<domain_id>/<topic name without its leading slash>/<DDS type name>/<RIHS01 type hash>``,
its payload the message in CDR (ros2/rmw_zenoh, docs/design.md). The bridge subscribes to
those keys with the hash chunk wildcarded (a sender's hash differing from lessmap's is logged
once: its definition differs, and decoding may fail), decodes with rosbags, and publishes
one frame per message through a lessmap ``RobotPublisher`` per robot. The robot is the
topic's ROS namespace (``/amr7/detections`` is robot ``amr7``; nested namespaces are joined
with dots) unless one robot name is given. A frame carries the robot's pose (from a pose
topic) nearest in time to the frame's stamp.

Zenoh's callback only queues the sample (bounded; a full queue counts the sample lost); the
bridge's own thread decodes and publishes, since a callback must not block or call Zenoh.
rmw_zenohd disables peer brokering, so the bridge connects to it as a Zenoh *client*.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import zenoh

from lessmap.ros import rmw
from lessmap.ros.msgtypes import dds_name, ros_name
from lessmap_client.errors import SessionClosedError
from lessmap_schemas import keys
from lessmap_schemas.errors import InvalidNameError, WireError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.ros.convert import Converter
    from lessmap_client.connection import Connection
    from lessmap_client.robot import RobotPublisher

log = logging.getLogger(__name__)

#: Poses kept per robot to pair with frames by stamp: Zenoh keeps the order of one key, not
#: across keys, so a detection may arrive before the odometry of the same instant.
POSE_HISTORY = 256


@dataclass(frozen=True, slots=True)
class TopicSpec:
    """A subscription: a topic name (relative to any namespace, or absolute), or a type."""

    key: str  # the Zenoh key expression
    tail: int  # chunks at the end of the topic name that are not the namespace
    pose: bool  # its messages carry the robot's pose, not features


def topic_specs(
    domain: int, topics: Sequence[str], pose_topics: Sequence[str], landmark_types: Sequence[str]
) -> list[TopicSpec]:
    """Return the subscriptions for the named topics, or for every landmark type if none.

    A relative name (``detections``, ``camera/detections``) matches that topic in every
    namespace; an absolute one (``/amr7/detections``) only itself, and its namespace is
    everything but its last chunk. With no topic named, every topic carrying one of the
    landmark types is taken, its namespace being all but the last chunk of its name.
    """
    specs = []
    for names, pose in ((topics, False), (pose_topics, True)):
        for name in names:
            chunks = [c for c in name.split("/") if c]
            if not chunks or any(c in ("*", "**") or "$" in c for c in chunks):
                msg = f"{name!r} is not a ROS topic name"
                raise ValueError(msg)
            if name.startswith("/"):
                specs.append(TopicSpec(f"{domain}/{'/'.join(chunks)}/*/*", 1, pose))
            else:
                specs.append(TopicSpec(f"{domain}/**/{'/'.join(chunks)}/*/*", len(chunks), pose))
    if not topics:
        specs += [TopicSpec(f"{domain}/**/{dds_name(t)}/*", 1, False) for t in landmark_types]
    return specs


class RosBridge:
    """Subscribe to rmw_zenoh topics on ``session``; publish frames through ``conn``.

    Args:
        session: an open Zenoh session on the ROS 2 network (a client of rmw_zenohd).
        conn: the lessmap connection the robots publish on (may wrap the same session).
        fleet: the fleet every robot is in.
        converter: decodes messages and reads their features, stamp and pose.
        specs: the subscriptions (``topic_specs``).
        robot: one robot name for every message, instead of the ROS namespace.
        root_robot: the robot name of topics in the root namespace.
        queue_depth: samples waiting for the bridge's thread; more are counted as lost.
        wait_service_s: before a robot's first frame, wait up to this long for the lessmap
            instance that serves it (frames sent earlier wait in the robot's cache).
    """

    def __init__(
        self,
        session: zenoh.Session,
        conn: Connection,
        fleet: str,
        converter: Converter,
        specs: Sequence[TopicSpec],
        *,
        robot: str | None = None,
        root_robot: str = "robot",
        queue_depth: int = 10000,
        wait_service_s: float = 2.0,
    ) -> None:
        self.fleet = keys.validate_name(fleet, "fleet")
        self.converter = converter
        self.specs = list(specs)
        self.robot = None if robot is None else keys.validate_name(robot, "robot")
        self.root_robot = keys.validate_name(root_robot, "robot")
        self.wait_service_s = wait_service_s
        self.counts: Counter[str] = converter.counts
        self._session = session
        self._conn = conn
        self._queue: queue.Queue[tuple[TopicSpec, str, bytes] | None] = queue.Queue(queue_depth)
        self._subscribers: list[zenoh.Subscriber[None]] = []
        self._robots: dict[str, RobotPublisher] = {}
        self._seen: set[str] = set()
        self._namespaces: dict[str, str] = {}
        self._poses: dict[str, deque[tuple[float, tuple[float, float, float]]]] = {}
        self._hash_checked: set[tuple[str, str]] = set()
        self._thread = threading.Thread(target=self._run, name="lessmap-ros", daemon=True)
        self._lock = threading.Lock()

    def start(self) -> RosBridge:
        """Declare the subscribers and start the bridge's thread."""
        self._thread.start()
        for spec in self.specs:
            self._subscribers.append(
                self._session.declare_subscriber(spec.key, self._callback(spec))
            )
            log.info("subscribed to %s", spec.key)
        return self

    def robots(self) -> list[str]:
        """Return the names of the robots published so far."""
        with self._lock:
            return sorted(self._seen)

    def namespace_of(self, robot: str) -> str:
        """Return the ROS namespace a robot's messages came from (else one made of its name)."""
        with self._lock:
            found = self._namespaces.get(robot)
        return rmw.ros_namespace(robot, self.root_robot) if found is None else found

    def stop(self, timeout_s: float = 5.0) -> None:
        """Undeclare the subscribers, handle what was queued, end every robot's session."""
        for sub in self._subscribers:
            sub.undeclare()
        self._subscribers.clear()
        self._queue.put(None)
        self._thread.join(timeout_s)
        with self._lock:
            robots, self._robots = dict(self._robots), {}
        for publisher in robots.values():
            publisher.close()

    # -- Zenoh's thread ----------------------------------------------------------------------

    def _callback(self, spec: TopicSpec) -> zenoh.handlers.Callback[zenoh.Sample]:
        def on_sample(sample: zenoh.Sample) -> None:
            try:
                self._queue.put_nowait((spec, str(sample.key_expr), sample.payload.to_bytes()))
            except queue.Full:
                self.converter.lost("bridge queue full", "messages arrive faster than handled")

        return zenoh.handlers.Callback(on_sample)

    # -- the bridge's thread -----------------------------------------------------------------

    def _run(self) -> None:
        while (item := self._queue.get()) is not None:
            spec, key, payload = item
            try:
                self._handle(spec, key, payload)
            except Exception:  # one bad message must not end the bridge
                log.exception("cannot handle a message on %s", key)
                self.counts["lost: failed"] += 1

    def _handle(self, spec: TopicSpec, key: str, payload: bytes) -> None:
        self.counts["received"] += 1
        chunks = key.split("/")
        type_name = ros_name(chunks[-2]) if len(chunks) >= 4 else None
        if type_name is None:
            self.converter.lost("unsupported key", f"{key} is not an rmw_zenoh topic key")
            return
        self._check_hash(type_name, chunks[-1])
        robot = self._robot_of(chunks[1:-2], spec.tail)
        if robot is None:
            return
        if spec.pose or self.converter.is_pose_type(type_name):
            if not self.converter.is_pose_type(type_name):
                self.converter.lost(
                    f"no pose type {type_name}", "pose topics carry Odometry or Pose*Stamped"
                )
                return
            message = self.converter.decode(type_name, payload)
            pose = None if message is None else self.converter.pose(type_name, message)
            if pose is not None:
                stamp = self.converter.stamp(message)
                history = self._poses.setdefault(robot, deque(maxlen=POSE_HISTORY))
                history.append((time.time() if stamp is None else stamp, pose))
                self.counts["poses"] += 1
            return
        if not self.converter.is_landmark_type(type_name):
            self.converter.lost(
                f"unsupported type {type_name}", "name its feature IDs with --ids TYPE=PATH"
            )
            return
        message = self.converter.decode(type_name, payload)
        if message is None:
            return
        features = self.converter.features(type_name, message)
        if features is None:
            return
        stamp = self.converter.stamp(message)
        stamp_s = time.time() if stamp is None else stamp
        try:
            self._publisher(robot).publish(
                features, stamp_s=stamp_s, pose=self._pose_at(robot, stamp_s)
            )
        except SessionClosedError as exc:
            self.converter.lost("robot name taken", f"{exc} (another publisher of that robot?)")
            return
        except WireError as exc:
            self.converter.lost(f"refused {exc.code}", str(exc))
            return
        self.counts["frames"] += 1

    def _pose_at(self, robot: str, stamp_s: float) -> tuple[float, float, float] | None:
        """Return the robot's received pose nearest in time to ``stamp_s``, if any."""
        history = self._poses.get(robot)
        if not history:
            return None
        return min(history, key=lambda entry: abs(entry[0] - stamp_s))[1]

    def _robot_of(self, topic: list[str], tail: int) -> str | None:
        if self.robot is not None:
            return self.robot
        namespace = topic[: max(0, len(topic) - tail)]
        if not namespace:
            return self.root_robot
        try:
            robot = keys.validate_name(".".join(namespace), "robot")
        except InvalidNameError as exc:
            self.converter.lost("bad robot name", f"{exc}; give one with --robot NAME")
            return None
        if robot not in self._namespaces:
            with self._lock:
                self._namespaces[robot] = "/" + "/".join(namespace)
        return robot

    def _publisher(self, robot: str) -> RobotPublisher:
        publisher = self._robots.get(robot)
        if publisher is None:
            publisher = self._conn.robot(self.fleet, robot)
            with self._lock:
                self._robots[robot] = publisher
                self._seen.add(robot)
            log.info(
                "robot %s/%s: first frame (partition %d)", self.fleet, robot, publisher.partition
            )
            if self.wait_service_s > 0 and not publisher.wait_for_service(self.wait_service_s):
                log.warning("robot %s/%s: no lessmap instance serves it yet", self.fleet, robot)
        return publisher

    def _check_hash(self, type_name: str, hash_chunk: str) -> None:
        if (type_name, hash_chunk) in self._hash_checked:
            return
        self._hash_checked.add((type_name, hash_chunk))
        try:
            ours = self.converter.store.hash_rihs01(type_name)
        except Exception:  # an unknown type: reported when its message is decoded
            return
        if hash_chunk != ours:
            log.warning(
                "%s: the sender's type hash %s is not lessmap's %s (another definition of "
                "the type: decoding may fail; register yours with --msg-def)",
                type_name,
                hash_chunk,
                ours,
            )

"""rmw_zenoh's formats: the keys, tokens and attachment a ROS 2 node expects of a publisher.

As ros2/rmw_zenoh writes them (docs/design.md; ``liveliness_utils.cpp`` and
``attachment_helpers.cpp`` of its Jazzy releases from 0.2.4 on, Kilted and Rolling):

1. Data key: ``<domain>/<topic without its leading slash>/<DDS type>/<RIHS01 type hash>``.
2. Liveliness token: ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/
   <namespace>/<node>``, then for a publisher (kind ``MP``) ``/<topic>/<DDS type>/<hash>/
   <qos>``. A ``/`` inside a name is written ``%``, so the root namespace is ``%``.
3. QoS chunk: ``reliability:durability:history,depth:deadline s,ns:lifespan s,ns:
   liveliness,lease s,ns``, each field empty where it equals rmw_zenoh's default (reliable,
   transient local, keep last 42, infinite durations, automatic liveliness).
4. Every sample carries an attachment: int64 sequence number, int64 source timestamp (ns),
   then the 16-byte publisher GID with its length (zenoh-ext serialization, little-endian).

Pure: strings and bytes in and out; the Zenoh side is ``ros/publisher.py``.
"""

from __future__ import annotations

import hashlib
import re
import struct
from dataclasses import dataclass

from lessmap.ros.msgtypes import dds_name

ADMIN_SPACE = "@ros2_lv"
NODE = "NN"
PUBLISHER = "MP"

#: rmw's enum values (rmw/types.h) written in the QoS chunk.
RELIABILITY_RELIABLE, RELIABILITY_BEST_EFFORT = 1, 2
DURABILITY_TRANSIENT_LOCAL, DURABILITY_VOLATILE = 1, 2
HISTORY_KEEP_LAST = 1
#: rmw_zenoh's default QoS (``qos.cpp``): a field equal to it is left empty in the chunk.
DEFAULT_DEPTH = 42

_ROS_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True, slots=True)
class Qos:
    """The QoS lessmap's publishers offer: volatile (no late-joiner cache), reliable."""

    reliable: bool = True
    depth: int = 10

    def chunk(self) -> str:
        """Return the QoS chunk of a liveliness token (rule 3)."""
        reliability = "" if self.reliable else str(RELIABILITY_BEST_EFFORT)
        depth = "" if self.depth == DEFAULT_DEPTH else str(self.depth)
        return f"{reliability}:{DURABILITY_VOLATILE}:,{depth}:,:,:,,"


def mangle(name: str) -> str:
    """Return a ROS name as one key chunk: every ``/`` becomes ``%`` (rule 2)."""
    return name.replace("/", "%")


def data_key(domain: int, topic: str, type_name: str, type_hash: str) -> str:
    """Return the Zenoh key of a topic's messages (rule 1)."""
    return f"{domain}/{topic.strip('/')}/{dds_name(type_name)}/{type_hash}"


def node_token(domain: int, zid: str, node_id: int, namespace: str, node: str) -> str:
    """Return the liveliness token of a node (rule 2; the node's own id is its entity id)."""
    fields = [ADMIN_SPACE, str(domain), zid, str(node_id), str(node_id), NODE, "%"]
    return "/".join([*fields, mangle(namespace or "/"), node])


@dataclass(frozen=True, slots=True)
class TopicInfo:
    """What a publisher's token says of its topic."""

    name: str  # fully qualified: /amr7/lessmap/transitions
    type_name: str  # lessmap_msgs/msg/Transition
    type_hash: str  # RIHS01_<64 hex digits>
    qos: Qos = Qos()


def publisher_token(
    domain: int, zid: str, node_id: int, entity_id: int, node: str, topic: TopicInfo
) -> str:
    """Return the liveliness token of a publisher of a node in the root namespace (rule 2)."""
    fields = [ADMIN_SPACE, str(domain), zid, str(node_id), str(entity_id), PUBLISHER, "%", "%"]
    about = [mangle(topic.name), dds_name(topic.type_name), topic.type_hash, topic.qos.chunk()]
    return "/".join([*fields, node, *about])


def gid_of(token: str) -> bytes:
    """Return a publisher's 16-byte GID, a hash of its token as rmw_zenoh derives it.

    rmw_zenoh takes XXH3-128 of the token; any stable 16 bytes serve (subscribers only
    compare GIDs), so the standard library's BLAKE2b stands in for it.
    """
    return hashlib.blake2b(token.encode(), digest_size=16).digest()


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """Return the attachment of one sample (rule 4)."""
    if len(gid) != 16:
        msg = f"a GID has 16 bytes, not {len(gid)}"
        raise ValueError(msg)
    return struct.pack("<qqB", seq, stamp_ns, len(gid)) + gid


def ros_namespace(robot: str, root_robot: str) -> str:
    """Return the ROS namespace of a robot: ``/`` + its name, dots as ``/``; root for one.

    The inverse of the bridge's naming (``/site/amr2`` is robot ``site.amr2``); characters a
    ROS name does not allow become ``_``, and a chunk starting with a digit gets one in front.
    """
    if robot == root_robot:
        return ""
    chunks = []
    for chunk in robot.split("."):
        clean = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", chunk)) or "_"
        chunks.append(clean if _ROS_TOKEN.match(clean) else f"_{clean}")
    return "/" + "/".join(chunks)

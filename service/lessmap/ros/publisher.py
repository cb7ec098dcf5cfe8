"""lessmap's transitions out to ROS 2: one rmw_zenoh publisher per robot and topic.

For each transition, ``RosPublisher.publish`` puts a ``lessmap_msgs/msg/Transition`` on
``<robot namespace>/lessmap/transitions`` and a ``lessmap_msgs/msg/AreaChange`` on
``<robot namespace>/lessmap/area``, in CDR, on rmw_zenoh's data key with its attachment. The
ROS graph learns of them as rmw_zenoh's nodes do, from liveliness tokens: one for the node
(``lessmap`` in the root namespace) and one per topic publisher (formats: ``ros/rmw.py``).

Invariants:

1. One thread calls ``publish`` (the transitions subscription's handler thread), then
   ``close`` once, after that subscription is closed: the publishers have one owner.
2. A publisher's token is declared before its first message, so a ROS subscriber that
   discovers the topic from the token sees every message after it.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import zenoh

from lessmap.ros import rmw
from lessmap.ros.outgoing import TOPICS, messages_of

if TYPE_CHECKING:
    from collections.abc import Callable

    from rosbags.typesys.store import Typestore

    from lessmap_schemas.messages import Transition

log = logging.getLogger(__name__)

#: rmw_zenoh numbers a context's nodes and entities from 0; lessmap's node is the only one.
NODE_ID = 0


@dataclass(slots=True)
class _Topic:
    publisher: zenoh.Publisher
    token: zenoh.LivelinessToken
    token_key: str
    gid: bytes
    sent: int = 0


class RosPublisher:
    """Publish lessmap transitions as ROS 2 topics on an rmw_zenoh network.

    Args:
        session: an open Zenoh session on the ROS 2 network.
        store: a type store with lessmap_msgs registered (``msgtypes.typestore()``).
        domain: the ROS domain id.
        namespace_of: the ROS namespace of a robot name (``""`` for the root namespace).
        node: the ROS node name the publishers belong to.
    """

    def __init__(
        self,
        session: zenoh.Session,
        store: Typestore,
        *,
        domain: int,
        namespace_of: Callable[[str], str],
        node: str = "lessmap",
    ) -> None:
        self.domain = domain
        self.node = node
        self.published = 0
        self._session = session
        self._store = store
        self._namespace_of = namespace_of
        self._zid = str(session.zid())
        self._topics: dict[str, _Topic] = {}
        # publish runs on a Zenoh callback thread: close waits for it and then refuses it
        self._lock = threading.Lock()
        self._closed = False
        self.node_token = rmw.node_token(domain, self._zid, NODE_ID, "", node)
        self._node_token = session.liveliness().declare_token(self.node_token)

    def publish(self, t: Transition) -> None:
        """Put ``t`` on its robot's transitions topic and its area change on the area topic."""
        namespace = self._namespace_of(t.robot)
        stamp_ns = time.time_ns()
        with self._lock:
            if self._closed:
                return
            for suffix, payload in messages_of(self._store, t).items():
                topic = self._topic(f"{namespace}/{suffix}", TOPICS[suffix])
                attachment = rmw.attachment(topic.sent, stamp_ns, topic.gid)
                topic.publisher.put(payload, attachment=attachment)
                topic.sent += 1
            self.published += 1

    def tokens(self) -> list[str]:
        """Return the liveliness tokens declared: the node's, then its publishers'."""
        return [self.node_token, *(t.token_key for t in self._topics.values())]

    def close(self) -> None:
        """Undeclare every publisher and token (the ROS graph sees them leave)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for topic in self._topics.values():
            topic.token.undeclare()
            topic.publisher.undeclare()
        self._topics.clear()
        self._node_token.undeclare()

    def _topic(self, name: str, type_name: str) -> _Topic:
        found = self._topics.get(name)
        if found is not None:
            return found
        info = rmw.TopicInfo(name, type_name, self._store.hash_rihs01(type_name))
        token = rmw.publisher_token(
            self.domain, self._zid, NODE_ID, len(self._topics) + 1, self.node, info
        )
        key = rmw.data_key(self.domain, name, type_name, info.type_hash)
        topic = _Topic(
            publisher=self._session.declare_publisher(key),
            token=self._session.liveliness().declare_token(token),
            token_key=token,
            gid=rmw.gid_of(token),
        )
        self._topics[name] = topic
        log.info("ROS 2 topic %s (%s) on %s", name, type_name, key)
        return topic

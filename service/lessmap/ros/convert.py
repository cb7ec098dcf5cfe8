"""One ROS message to one lessmap frame, with every message that does not convert counted.

Shared by the live bridge and the bag import, so both read a message the same way. Nothing
is dropped silently: each kind of loss (a payload that does not decode, a type no ID path
names, IDs that cannot be read, a frame over the feature limit) is counted in ``counts`` and
logged once, at the first occurrence, with what to do about it.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import TYPE_CHECKING

from lessmap.ros.extract import POSE_PATHS, pose_of, stamp_of

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

    from lessmap.ros.extract import IdPath

log = logging.getLogger(__name__)


class Converter:
    """Decode messages of known types; return their feature IDs, stamp and pose.

    Args:
        store: the rosbags type store the messages' types are registered in.
        id_paths: message type to the ID path of its features.
        max_features: the wire's ``max_features_per_frame``; a larger frame is refused here.
    """

    def __init__(
        self, store: Typestore, id_paths: dict[str, IdPath], *, max_features: int = 4096
    ) -> None:
        self.store = store
        self.id_paths = id_paths
        self.max_features = max_features
        self.counts: Counter[str] = Counter()
        self._warned: set[str] = set()

    def is_landmark_type(self, type_name: str) -> bool:
        """Return whether messages of ``type_name`` carry features."""
        return type_name in self.id_paths

    def is_pose_type(self, type_name: str) -> bool:
        """Return whether messages of ``type_name`` carry the robot's pose."""
        return type_name in POSE_PATHS

    def decode(
        self, type_name: str, payload: bytes | memoryview, *, ros1: bool = False
    ) -> object | None:
        """Return the decoded message, or None (counted) when it does not decode."""
        if type_name not in self.store.types:
            self.lost(
                f"unknown type {type_name}",
                "register its definition with --msg-def TYPE=FILE.msg",
            )
            return None
        try:
            if ros1:
                return self.store.deserialize_ros1(bytes(payload), type_name)
            return self.store.deserialize_cdr(bytes(payload), type_name)
        except Exception as exc:  # rosbags raises several kinds for bytes that do not fit
            self.lost(
                f"undecodable {type_name}",
                f"not this type in CDR; is the sender's definition another? ({exc})",
            )
            return None

    def features(self, type_name: str, message: object) -> list[int] | None:
        """Return the distinct feature IDs of a landmark message, or None (counted)."""
        path = self.id_paths[type_name]
        try:
            ids = list(dict.fromkeys(path.ids(message)))
        except ValueError as exc:
            self.lost(f"no IDs in {type_name}", f"ID path {path.text!r}: {exc}; fix it with --ids")
            return None
        if not ids:
            self.counts["empty"] += 1  # nothing seen: no frame (not a loss)
            return None
        if len(ids) > self.max_features:
            self.lost(
                "over max_features_per_frame",
                f"{len(ids)} features in one {type_name}, the wire allows {self.max_features}",
            )
            return None
        return ids

    def pose(self, type_name: str, message: object) -> tuple[float, float, float] | None:
        """Return the planar pose of a pose message, or None (counted) if not finite."""
        try:
            found = pose_of(message, POSE_PATHS[type_name])
        except AttributeError as exc:
            self.lost(f"no pose in {type_name}", str(exc))
            return None
        if found is None:
            self.lost(f"no pose in {type_name}", "a coordinate is not finite")
        return found

    @staticmethod
    def stamp(message: object) -> float | None:
        """Return the message's header stamp in seconds, if it has a non-zero one."""
        return stamp_of(message)

    def lost(self, kind: str, why: str) -> None:
        """Count one message lost for ``kind``; log the first of each kind."""
        self.counts[f"lost: {kind}"] += 1
        if kind not in self._warned:
            self._warned.add(kind)
            log.warning("%s: %s (further ones are counted, not logged)", kind, why)

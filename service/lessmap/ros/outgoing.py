"""lessmap's transitions as ROS 2 messages: the ``lessmap_msgs`` package and the conversion.

The ``.msg`` files in ``lessmap_msgs/msg/`` are the definitions both sides use: lessmap
registers them in its rosbags type store (the CDR layout and the RIHS01 hash follow their
text), and a ROS 2 workspace builds the same folder (an ament package) so that nodes and
``ros2 topic echo`` know the types. Pure: a ``Transition`` in, CDR bytes out.
"""

from __future__ import annotations

import math
from importlib import resources
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

    from lessmap_schemas.messages import SubmapSummary, Transition

PACKAGE = "lessmap_msgs"
SUBMAP_SUMMARY = f"{PACKAGE}/msg/SubmapSummary"
TRANSITION = f"{PACKAGE}/msg/Transition"
AREA_CHANGE = f"{PACKAGE}/msg/AreaChange"
#: Topics under each robot's namespace, and the type each carries.
TOPICS = {"lessmap/transitions": TRANSITION, "lessmap/area": AREA_CHANGE}

_INT32_MAX = 2**31 - 1


def definitions() -> dict[str, str]:
    """Return type name to ``.msg`` text of lessmap_msgs, nested types first."""
    folder = resources.files("lessmap.ros").joinpath(PACKAGE, "msg")
    return {
        f"{PACKAGE}/msg/{name}": folder.joinpath(f"{name}.msg").read_text(encoding="utf-8")
        for name in ("SubmapSummary", "Transition", "AreaChange")
    }


def header(store: Typestore, stamp_s: float) -> Any:
    """Return a ``std_msgs/Header`` stamped ``stamp_s`` (clamped to ROS time's int32 range)."""
    sec = math.floor(stamp_s)
    nanosec = min(999_999_999, round((stamp_s - sec) * 1e9))
    if not -_INT32_MAX - 1 <= sec <= _INT32_MAX:
        sec, nanosec = max(-_INT32_MAX - 1, min(_INT32_MAX, sec)), 0
    stamp = store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="")


def _submap(store: Typestore, summary: SubmapSummary) -> Any:
    import numpy as np

    return store.types[SUBMAP_SUMMARY](
        id=summary.id,
        first_seq=summary.first_seq,
        last_seq=summary.last_seq,
        frame_count=summary.frame_count,
        features=np.array(summary.features, dtype=np.int64),
    )


def transition_message(store: Typestore, t: Transition) -> Any:
    """Return ``t`` as a ``lessmap_msgs/msg/Transition`` (a null ncut or lambda2 is NaN)."""
    import numpy as np

    return store.types[TRANSITION](
        header=header(store, t.stamp_s),
        fleet=t.fleet,
        robot=t.robot,
        session=t.session,
        incarnation=t.incarnation,
        seq=t.seq,
        boundary_seq=t.boundary_seq,
        reason=t.reason,
        ncut=math.nan if t.ncut is None else t.ncut,
        lambda2=math.nan if t.lambda2 is None else t.lambda2,
        closed=_submap(store, t.closed),
        opened=_submap(store, t.opened),
        boundary_features=np.array(t.boundary_features, dtype=np.int64),
        area=t.area,
        left_area=t.left_area,
        revisit=t.revisit,
        batch_frames=t.batch_frames,
        instance=t.instance,
        partition=t.partition,
        epoch=t.epoch,
    )


def area_change_message(store: Typestore, t: Transition) -> Any:
    """Return the area change of ``t`` as a ``lessmap_msgs/msg/AreaChange``."""
    return store.types[AREA_CHANGE](
        header=header(store, t.stamp_s),
        fleet=t.fleet,
        robot=t.robot,
        session=t.session,
        seq=t.seq,
        area=t.area,
        left_area=t.left_area,
        revisit=t.revisit,
    )


def messages_of(store: Typestore, t: Transition) -> dict[str, bytes]:
    """Return the CDR payload for each topic of ``TOPICS``, by topic."""
    built = {TRANSITION: transition_message(store, t), AREA_CHANGE: area_change_message(store, t)}
    return {
        topic: bytes(store.serialize_cdr(built[type_name], type_name))
        for topic, type_name in TOPICS.items()
    }

"""Key expressions of every lessmap stream, one function per stream.

Layout under `KEY_PREFIX` (in full: schemas/README.md section 2), then rules of this file:

    lessmap/v4/<fleet>/<robot>/{frames/<p>, transitions, errors, state, areas, submaps/<id>}
    lessmap/v4/@/{instances, health, errors}/<instance>, .../@/{checkpoints, released}/<p>/...

1. `<p>` is the robot's partition (`partition.partition_of`), the last chunk of its frames
   key, so an instance may subscribe to the partitions it owns only.
2. Service bookkeeping sits under `@`: Zenoh never lets `*` or `**` match a chunk that starts
   with `@`, so a fleet-wide `lessmap/v4/**` subscription sees robot traffic only.
3. A fleet or robot may be `"*"` to subscribe, declare a queryable or query; publishers pass
   concrete names, which `validate_name` checks.
"""

from __future__ import annotations

import re

from lessmap_schemas.errors import InvalidNameError
from lessmap_schemas.limits import DEFAULT_LIMITS, MAX_SEQ, WireLimits
from lessmap_schemas.partition import PARTITIONS, partition_of

WIRE_VERSION = 4
"""Value of the `v` field of every message and of the `v4` key chunk."""
KEY_PREFIX = f"lessmap/v{WIRE_VERSION}"
"""First two chunks of every key; the version chunk changes only on a breaking change."""
NAME_PATTERN = r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$"
"""Names: ASCII letters, digits, `_`, `.`, `-`; not starting with `.` or `-`; 1..64 chars."""
ANY = "*"
"""Wildcard for exactly one fleet, robot or instance chunk."""
ROBOT_STREAMS = ("frames", "transitions", "errors", "state", "areas")
"""Streams of `lessmap/v4/<fleet>/<robot>/<stream>` keys; frames and submaps have one more chunk."""

_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*")
_FIRST = re.compile(r"[A-Za-z0-9_]")
_REST = re.compile(r"[A-Za-z0-9_.\-]")
_ID = re.compile(r"0|[1-9][0-9]*")


def validate_name(value: str, what: str = "robot", limits: WireLimits = DEFAULT_LIMITS) -> str:
    """Check a fleet, robot, session or instance name and return it unchanged.

    Args:
        value: The name. Wildcards are not names: pass `"*"` only to the key helpers.
        what: What the name is, for the error message ("fleet", "robot", "session", ...).
        limits: Supplies `max_name_len`.

    Returns:
        `value`.

    Raises:
        InvalidNameError: Not a str, empty, too long, or a character outside the rule; the
            message names `what` and the first bad character.
    """
    if type(value) is not str:
        msg = f"{what} name must be a str, not {type(value).__name__}"
        raise InvalidNameError(msg)
    if len(value) > limits.max_name_len:
        msg = f"{what} name {value[:80]!r} is longer than {limits.max_name_len} characters"
        raise InvalidNameError(msg, limit="max_name_len")
    if _NAME.fullmatch(value) is None:
        raise InvalidNameError(_explain(value, what))
    return value


def _explain(value: str, what: str) -> str:
    if not value:
        return f"{what} name is empty"
    if _FIRST.fullmatch(value[0]) is None:
        return (
            f"{what} name {value!r} starts with {value[0]!r}; "
            "a name starts with a letter, digit or '_'"
        )
    index = next(i for i, char in enumerate(value) if _REST.fullmatch(char) is None)
    return (
        f"{what} name {value!r} has {value[index]!r} at index {index}; "
        "allowed are ASCII letters, digits, '_', '.' and '-'"
    )


def _chunk(value: str, what: str) -> str:
    return value if value == ANY else validate_name(value, what)


def _robot_key(fleet: str, robot: str, stream: str) -> str:
    return f"{KEY_PREFIX}/{_chunk(fleet, 'fleet')}/{_chunk(robot, 'robot')}/{stream}"


def frames(fleet: str, robot: str) -> str:
    """Return the key a robot puts `Frame` and `SessionEnd` on (one key keeps their order).

    The last chunk is the robot's partition. With a wildcard fleet or robot the partition
    chunk is a wildcard too (a subscription to every partition of those robots).
    """
    key = _robot_key(fleet, robot, "frames")
    if ANY in (fleet, robot):
        return f"{key}/{ANY}"
    return f"{key}/{partition_of(fleet, robot)}"


def frames_of_partition(partition: int) -> str:
    """Return the key expression of every robot's frames in one partition (a subscription)."""
    return f"{KEY_PREFIX}/{ANY}/{ANY}/frames/{_partition_chunk(partition)}"


def frames_of_every_partition() -> str:
    """Return the key expression of every robot's frames (one subscription for all)."""
    return f"{KEY_PREFIX}/{ANY}/{ANY}/frames/{ANY}"


def _partition_chunk(partition: int) -> str:
    if type(partition) is not int or not 0 <= partition < PARTITIONS:
        msg = f"partition must be an int in [0, {PARTITIONS - 1}], not {partition!r}"
        raise InvalidNameError(msg)
    return str(partition)


def transitions(fleet: str = ANY, robot: str = ANY) -> str:
    """Return the key the service puts `Transition` messages on."""
    return _robot_key(fleet, robot, "transitions")


def errors(fleet: str = ANY, robot: str = ANY) -> str:
    """Return the key the service puts `Error` messages on."""
    return _robot_key(fleet, robot, "errors")


def state(fleet: str, robot: str) -> str:
    """Return the key the service answers with the robot's `SessionState`."""
    return _robot_key(fleet, robot, "state")


def areas(fleet: str, robot: str) -> str:
    """Return the key the service answers with the robot's `AreaGraph`."""
    return _robot_key(fleet, robot, "areas")


def submap(fleet: str, robot: str, submap_id: int) -> str:
    """Return the key the service answers with one `Submap` of the robot's session."""
    if type(submap_id) is not int or not 0 <= submap_id <= MAX_SEQ:
        msg = f"submap id must be an int in [0, 2**53-1], not {submap_id!r}"
        raise InvalidNameError(msg)
    return f"{_robot_key(fleet, robot, 'submaps')}/{submap_id}"


def submaps(fleet: str, robot: str) -> str:
    """Return the key that queries every `Submap` of the robot's session."""
    return f"{_robot_key(fleet, robot, 'submaps')}/{ANY}"


def instance_token(instance: str) -> str:
    """Return the liveliness token key a service instance declares while it runs."""
    return f"{KEY_PREFIX}/@/instances/{validate_name(instance, 'instance')}"


def instances() -> str:
    """Return the key that matches the liveliness tokens of every service instance."""
    return f"{KEY_PREFIX}/@/instances/{ANY}"


def health(instance: str = ANY) -> str:
    """Return the key a service instance answers with its `Health`."""
    return f"{KEY_PREFIX}/@/health/{_chunk(instance, 'instance')}"


def checkpoints(partition: int | str = ANY, fleet: str = ANY, robot: str = ANY) -> str:
    """Return the key of a session checkpoint shipped between service instances.

    Service bookkeeping: the owner of a partition puts its sessions' checkpoints here for the
    standby, and every instance answers queries for the checkpoints it holds. Pass `"*"` for
    any chunk to subscribe or query.
    """
    chunk = ANY if partition == ANY else _partition_chunk(partition)  # type: ignore[arg-type]
    return f"{KEY_PREFIX}/@/checkpoints/{chunk}/{_chunk(fleet, 'fleet')}/{_chunk(robot, 'robot')}"


def parse_checkpoint_key(key: str) -> tuple[int, str, str]:
    """Split a concrete `lessmap/v4/@/checkpoints/<p>/<fleet>/<robot>` key."""
    parts = key.split("/") if type(key) is str else []
    prefix = f"{KEY_PREFIX}/@/checkpoints"
    if len(parts) != 7 or "/".join(parts[:4]) != prefix or _ID.fullmatch(parts[4]) is None:
        msg = f"key {str(key)[:200]!r} is not {prefix}/<p>/<fleet>/<robot>"
        raise InvalidNameError(msg)
    partition = int(parts[4])
    fleet, robot = validate_name(parts[5], "fleet"), validate_name(parts[6], "robot")
    if partition != partition_of(fleet, robot):
        msg = f"key {key[:200]!r}: {fleet}/{robot} is in partition {partition_of(fleet, robot)}"
        raise InvalidNameError(msg)
    return partition, fleet, robot


def released(partition: int | str = ANY, instance: str = ANY) -> str:
    """Return the key a service instance puts on when it has handed a partition over.

    Service bookkeeping: the former owner puts here once its final checkpoints of the
    partition are in its store, so a new owner waiting for it fetches them only then. Pass
    `"*"` for any chunk to subscribe.
    """
    chunk = ANY if partition == ANY else _partition_chunk(partition)  # type: ignore[arg-type]
    return f"{KEY_PREFIX}/@/released/{chunk}/{_chunk(instance, 'instance')}"


def parse_released_key(key: str) -> tuple[int, str]:
    """Split a concrete `lessmap/v4/@/released/<p>/<instance>` key: (partition, instance)."""
    parts = key.split("/") if type(key) is str else []
    prefix = f"{KEY_PREFIX}/@/released"
    if len(parts) != 6 or "/".join(parts[:4]) != prefix or _ID.fullmatch(parts[4]) is None:
        msg = f"key {str(key)[:200]!r} is not {prefix}/<p>/<instance>"
        raise InvalidNameError(msg)
    partition = int(parts[4])
    _partition_chunk(partition)  # in range, else InvalidNameError
    return partition, validate_name(parts[5], "instance")


def service_errors(instance: str = ANY) -> str:
    """Return the key a service instance puts `Error`s on when the key names no valid robot."""
    return f"{KEY_PREFIX}/@/errors/{_chunk(instance, 'instance')}"


def parse_robot_key(key: str) -> tuple[str, str, str]:
    """Split a concrete `lessmap/v4/<fleet>/<robot>/<stream>` key.

    Args:
        key: A key a sample arrived on, e.g. `lessmap/v4/warehouse/amr-7/frames`.

    Returns:
        `(fleet, robot, stream)`, stream one of `ROBOT_STREAMS`.

    Raises:
        InvalidNameError: Another prefix or stream, a wildcard, or a name breaking the rule.
    """
    fleet, robot, rest = _split(key, 5, 6)
    stream = rest[0]
    if stream not in ROBOT_STREAMS:
        msg = f"key {key[:200]!r} has stream {stream!r}; expected one of {', '.join(ROBOT_STREAMS)}"
        raise InvalidNameError(msg)
    if (stream == "frames") != (len(rest) == 2):
        msg = f"key {key[:200]!r}: only frames keys end with a partition chunk"
        raise InvalidNameError(msg)
    if stream == "frames":
        expected = partition_of(fleet, robot)
        if rest[1] != str(expected):
            msg = (
                f"key {key[:200]!r} names partition {rest[1][:20]!r}, "
                f"but {fleet}/{robot} is in partition {expected}"
            )
            raise InvalidNameError(msg)
    return fleet, robot, stream


def parse_submap_key(key: str) -> tuple[str, str, int]:
    """Split a concrete `lessmap/v4/<fleet>/<robot>/submaps/<id>` key.

    Args:
        key: A concrete submap key.

    Returns:
        `(fleet, robot, submap_id)`.

    Raises:
        InvalidNameError: Not a submap key, or a bad name or id.
    """
    fleet, robot, rest = _split(key, 6)
    stream, text = rest
    # One spelling per id: ASCII digits, no sign, no leading zero, at most MAX_SEQ.
    if (
        stream != "submaps"
        or _ID.fullmatch(text) is None
        or len(text) > len(str(MAX_SEQ))
        or int(text) > MAX_SEQ
    ):
        msg = f"key {key[:200]!r} is not {KEY_PREFIX}/<fleet>/<robot>/submaps/<id>"
        raise InvalidNameError(msg)
    return fleet, robot, int(text)


def _split(key: str, *chunks: int) -> tuple[str, str, list[str]]:
    if type(key) is not str:
        msg = f"key must be a str, not {type(key).__name__}"
        raise InvalidNameError(msg)
    parts = key.split("/")
    if len(parts) not in chunks or f"{parts[0]}/{parts[1]}" != KEY_PREFIX:
        msg = f"key {key[:200]!r} does not have the form {KEY_PREFIX}/<fleet>/<robot>/..."
        raise InvalidNameError(msg)
    return validate_name(parts[2], "fleet"), validate_name(parts[3], "robot"), parts[4:]

"""Partitions and their owners: the two functions every client and instance computes alike.

The contract, with the formulas, is schemas/README.md section 2a. Rules of this file:

1. A robot belongs to one of `PARTITIONS` partitions, a fixed function of its fleet and name
   (the first 8 bytes of a SHA-256, big-endian, modulo `PARTITIONS`); the partition is the
   last chunk of the robot's frames key, so Zenoh routes a partition's frames only to the
   instances that subscribed to it.
2. Each partition's owner and standby are the first two live instances ranked by rendezvous
   (highest random weight) hashing of `instance/partition`, highest score first, ties broken
   by name; everyone who sees the same liveliness tokens ranks the same way, and an instance
   that joins or leaves moves only the partitions it wins or held.
"""

from __future__ import annotations

from hashlib import sha256
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

PARTITIONS = 256
"""Number of partitions; fixed by the contract version (a change is a breaking change)."""


def _u64(text: str) -> int:
    return int.from_bytes(sha256(text.encode("utf-8")).digest()[:8], "big")


def partition_of(fleet: str, robot: str) -> int:
    """Return the partition of a robot, in [0, PARTITIONS)."""
    return _u64(f"{fleet}/{robot}") % PARTITIONS


def score(instance: str, partition: int) -> int:
    """Return the rendezvous weight of an instance for a partition (an unsigned 64-bit int)."""
    return _u64(f"{instance}/{partition}")


def ranking(partition: int, instances: Iterable[str]) -> list[str]:
    """Return the instances in the order they would serve a partition: owner, standby, ..."""
    return sorted(set(instances), key=lambda name: (-score(name, partition), name))


def owner_and_standby(partition: int, instances: Iterable[str]) -> tuple[str | None, str | None]:
    """Return the owner and the standby of a partition among live instances (None if absent)."""
    ranked = ranking(partition, instances)
    return (
        ranked[0] if ranked else None,
        ranked[1] if len(ranked) > 1 else None,
    )


def assignment(instances: Iterable[str]) -> dict[int, tuple[str | None, str | None]]:
    """Return `{partition: (owner, standby)}` for every partition."""
    live = sorted(set(instances))
    return {p: owner_and_standby(p, live) for p in range(PARTITIONS)}

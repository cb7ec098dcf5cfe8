"""Access control of the partitioned keys, on the router alone: frames partitions and checkpoints.

No ``lessmap serve`` runs: raw Zenoh sessions with the service's certificate play the
service instances (an owner subscribed per partition, an owner putting checkpoints, a
standby subscribed to them, every instance answering checkpoint queries), so these rules are
checked whatever the service does with them. Each refusal is checked next to a positive
control on the same sessions.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import pytest

from lessmap_schemas import keys
from lessmap_schemas.partition import PARTITIONS, partition_of
from tests.conftest import wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

    from tests.security.conftest import SecureSite

pytestmark = pytest.mark.timeout(120)

#: How long a refused message gets to show up anyway, after the positive control arrived.
QUIET_S = 1.0


class Collector:
    """A plain subscriber that records the keys and payloads it receives."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.got.append((str(sample.key_expr), sample.payload.to_bytes()))

    def payloads(self) -> set[bytes]:
        return {payload for _, payload in self.got}


def put_until(session: zenoh.Session, key: str, payload: bytes, seen: Callable[[], bool]) -> None:
    """Put ``payload`` on ``key`` until ``seen()`` (declarations take a moment to spread)."""

    def done() -> bool:
        if not seen():
            session.put(key, payload)
            time.sleep(0.05)
        return seen()

    wait_until(done, 20.0, f"{payload!r} on {key}")


def replies(session: zenoh.Session, key: str, timeout_s: float = 2.0) -> set[bytes]:
    """Return the payloads of the ok replies to a ``get`` on ``key``."""
    found = set()
    for reply in session.get(key, timeout=timeout_s):
        if reply.ok is not None:
            found.add(reply.ok.payload.to_bytes())
    return found


def answer_with(key: str, payload: bytes) -> Callable[[zenoh.Query], None]:
    """A queryable's callback that replies ``payload`` on ``key``."""

    def answer(query: zenoh.Query) -> None:
        query.reply(key, payload)

    return answer


def other_partition(partition: int) -> int:
    return (partition + 1) % PARTITIONS


@pytest.mark.usefixtures("router")
def test_a_robot_of_another_fleet_cannot_put_on_this_fleets_frames_partition(
    site: SecureSite, session_as: Callable[..., zenoh.Session]
) -> None:
    victim_p = partition_of(site.fleet, "victim")
    own_p = partition_of(site.other, "own")
    owner = session_as("service")
    # The owner's subscriptions: one per partition it owns (the service's shape).
    collectors = [Collector(owner, keys.frames_of_partition(p)) for p in {victim_p, own_p}]

    def got() -> set[bytes]:
        return set().union(*(c.payloads() for c in collectors))

    intruder = session_as("robot", site.other)  # robot.G: a valid certificate of this site
    robot = session_as("robot")  # robot.F
    # Positive controls: each robot feeds its own fleet, through the same router.
    put_until(intruder, keys.frames(site.other, "own"), b"G feeds G", lambda: b"G feeds G" in got())
    put_until(robot, keys.frames(site.fleet, "victim"), b"F feeds F", lambda: b"F feeds F" in got())
    # Robot G on F's robot's key: the right partition chunk, and another one.
    intruder.put(keys.frames(site.fleet, "victim"), b"G on F")
    wrong = f"{keys.KEY_PREFIX}/{site.fleet}/victim/frames/{other_partition(victim_p)}"
    intruder.put(wrong, b"G on F, other partition")
    spy = Collector(owner, keys.frames("*", "*"))  # every partition of every robot
    intruder.put(wrong, b"G on F, other partition")
    put_until(robot, keys.frames(site.fleet, "victim"), b"F again", lambda: b"F again" in got())
    time.sleep(QUIET_S)
    assert got() == {b"G feeds G", b"F feeds F", b"F again"}
    assert spy.payloads() <= {b"F again"}


@pytest.mark.usefixtures("router")
def test_apps_and_robots_can_neither_follow_nor_query_checkpoints(
    site: SecureSite, session_as: Callable[..., zenoh.Session]
) -> None:
    p = partition_of(site.fleet, "amr-1")
    key = keys.checkpoints(p, site.fleet, "amr-1")
    owner, standby = session_as("service"), session_as("service")
    holder = owner.declare_queryable(keys.checkpoints(p), answer_with(key, b"checkpoint"))
    outsiders = {
        "app.F": session_as("app"),
        "app.G": session_as("app", site.other),
        "robot.F": session_as("robot"),
    }
    spies = {
        name: Collector(s, f"{keys.KEY_PREFIX}/@/checkpoints/**") for name, s in outsiders.items()
    }
    narrow = {name: Collector(s, key) for name, s in outsiders.items()}
    followed = Collector(standby, keys.checkpoints())
    # Positive control: the standby receives the owner's checkpoint and can query it.
    put_until(owner, key, b"checkpoint", lambda: b"checkpoint" in followed.payloads())
    assert replies(standby, keys.checkpoints(p, "*", "*"), 5.0) == {b"checkpoint"}
    owner.put(key, b"checkpoint 2")
    wait_until(lambda: b"checkpoint 2" in followed.payloads(), 10.0, "the second checkpoint")
    time.sleep(QUIET_S)
    for name, session in outsiders.items():
        assert spies[name].got == [], name
        assert narrow[name].got == [], name
        assert replies(session, f"{keys.KEY_PREFIX}/@/checkpoints/**", 1.0) == set(), name
        assert replies(session, key, 1.0) == set(), name
    holder.undeclare()


@pytest.mark.usefixtures("router")
def test_no_robot_or_app_can_put_or_serve_a_forged_checkpoint(
    site: SecureSite, session_as: Callable[..., zenoh.Session]
) -> None:
    p = partition_of(site.fleet, "amr-1")
    key = keys.checkpoints(p, site.fleet, "amr-1")
    owner, standby = session_as("service"), session_as("service")
    followed = Collector(standby, keys.checkpoints())
    declared: list[zenoh.Queryable[None]] = []
    forgers = {
        "robot.F": session_as("robot"),
        "app.F": session_as("app"),
        "robot.G": session_as("robot", site.other),
    }
    for name, forger in forgers.items():
        forged = f"forged by {name}".encode()
        # A queryable that would answer a new owner's hand-over query with forged state.
        declared.append(forger.declare_queryable(keys.checkpoints(p), answer_with(key, forged)))
    # Positive control first: the owner's checkpoint reaches the standby on this path.
    put_until(owner, key, b"real", lambda: b"real" in followed.payloads())
    for name, forger in forgers.items():
        forger.put(key, f"forged by {name}".encode())
    declared.append(owner.declare_queryable(keys.checkpoints(p), answer_with(key, b"real")))
    put_until(owner, key, b"real again", lambda: b"real again" in followed.payloads())
    time.sleep(QUIET_S)
    assert followed.payloads() == {b"real", b"real again"}
    # The new owner's hand-over query: only the service's answer.
    assert replies(standby, keys.checkpoints(p, "*", "*"), 3.0) == {b"real"}
    for entity in declared:
        entity.undeclare()

"""Ownership without I/O: who owns what, epochs, the freeze fence; records that travel."""

from __future__ import annotations

import random

import pytest

from lessmap.runtime.ownership import Ownership
from lessmap.runtime.record import SessionRecord
from lessmap_schemas.partition import PARTITIONS, owner_and_standby, partition_of


class Clock:
    def __init__(self) -> None:
        self.now = 100.0
        self.wall = 1_000_000

    def mono(self) -> float:
        return self.now

    def wall_ms(self) -> int:
        return self.wall


def owner(instance: str, clock: Clock | None = None) -> Ownership:
    c = clock or Clock()
    return Ownership(instance, freeze_s=2.0, monotonic=c.mono, wall_ms=c.wall_ms)


def take(o: Ownership, live: list[str]) -> None:
    change = o.set_live(live)
    for p in change.lost:
        o.release(p)
    for p in change.gained:
        o.acquire(p)
    for p in change.standby_gained:
        o.set_standby(p, on=True)
    for p in change.standby_lost:
        o.set_standby(p, on=False)


def test_alone_an_instance_owns_every_partition() -> None:
    o = owner("a")
    change = o.set_live([])
    assert change.gained == list(range(PARTITIONS))
    assert change.standby_gained == []


def test_the_live_instances_share_every_partition_exactly_once() -> None:
    names = ["a", "b", "c"]
    owners = {name: owner(name) for name in names}
    for o in owners.values():
        take(o, names)
    owned = [p for o in owners.values() for p in o.owned()]
    assert sorted(owned) == list(range(PARTITIONS))
    standby = [p for o in owners.values() for p in o.standby()]
    assert sorted(standby) == list(range(PARTITIONS))
    for name, o in owners.items():
        assert set(o.owned()).isdisjoint(o.standby())
        for p in o.owned():
            assert owner_and_standby(p, names)[0] == name


def test_a_leave_moves_only_the_partitions_of_the_one_that_left() -> None:
    rng = random.Random(7)
    for _ in range(20):
        names = [f"i{rng.randrange(10**6)}" for _ in range(rng.randint(2, 6))]
        gone = rng.choice(names)
        for name in names:
            if name == gone:
                continue
            o = owner(name)
            take(o, names)
            before = set(o.owned())
            change = o.leave(gone)
            assert change.lost == []  # a leave never takes a partition away from a survivor
            for p in change.gained:
                assert owner_and_standby(p, names)[0] == gone
            assert before | set(change.gained) == {
                p for p in range(PARTITIONS) if owner_and_standby(p, set(names) - {gone})[0] == name
            }


def test_this_instance_never_leaves_its_own_view() -> None:
    o = owner("a")
    take(o, ["a", "b"])
    o.leave("a")
    assert "a" in o.live


def test_epochs_rise_for_a_partition_even_when_the_clock_does_not() -> None:
    clock = Clock()
    o = owner("a", clock)
    first = o.acquire(5)
    o.release(5)
    second = o.acquire(5)
    assert second > first  # same wall clock: one above the last
    o.saw_epoch(5, 10**12)  # a checkpoint of a later owner was taken over
    o.release(5)
    assert o.acquire(5) == 10**12 + 1


def test_the_fence_opens_only_for_owned_partitions() -> None:
    o = owner("a")
    take(o, ["a", "b"])
    mine = next(iter(o.owned()))
    robot = next(f"r{i}" for i in range(10_000) if partition_of("f", f"r{i}") == mine)
    other = next(f"r{i}" for i in range(10_000) if partition_of("f", f"r{i}") not in o.owned())
    assert o.epoch_for("f", robot) == o.owned()[mine]
    assert o.epoch_for("f", other) is None
    o.release(mine)
    assert o.epoch_for("f", robot) is None


def test_a_freeze_closes_the_fence_before_and_after_the_heartbeat_notices() -> None:
    clock = Clock()
    o = owner("a", clock)
    take(o, [])
    assert o.epoch_of(0) is not None
    clock.now += 1.0
    assert not o.tick()
    clock.now += 5.0  # SIGSTOP for 5 s: a worker that runs before the heartbeat is fenced
    assert o.epoch_of(0) is None
    assert o.tick()  # the heartbeat notices and drops everything
    assert o.owned() == {}
    assert o.epoch_of(0) is None
    assert o.freezes == 1
    take(o, [])  # rejoin: new epochs, above the old ones
    assert o.epoch_of(0) is not None


def record(epoch: int, last_seq: int | None, session: str = "s1") -> SessionRecord:
    return SessionRecord(
        fleet="f",
        robot="r",
        session=session,
        status="open",
        last_seq=last_seq,
        meta={"epoch": epoch, "frames_missing": 0},
        snapshot=b"\x00\x01snapshot",
        updated_s=12.5,
    )


def test_a_record_is_newer_by_epoch_then_by_seq() -> None:
    assert record(2, 5).newer_than(None)
    assert record(2, 5).newer_than(record(1, 900))
    assert record(2, 6).newer_than(record(2, 5))
    assert not record(2, 5).newer_than(record(2, 5))
    assert not record(1, 900).newer_than(record(2, None))


def test_a_record_travels_as_bytes_and_comes_back_equal() -> None:
    original = record(7, 42)
    assert SessionRecord.from_bytes(original.to_bytes()) == original


@pytest.mark.parametrize(
    "payload", [b"", b"\xc1", b"\x93\x01\x02\x03", b"\x81\xa4ckpt\x01", b"\x81\xa4ckpt\x02"]
)
def test_a_damaged_record_is_a_value_error(payload: bytes) -> None:
    with pytest.raises(ValueError, match="unreadable checkpoint record"):
        SessionRecord.from_bytes(payload)


def test_an_arriving_instance_is_handed_what_the_live_ones_own_and_nothing_else() -> None:
    a, b = owner("a"), owner("b")
    take(a, ["a"])
    change = b.set_live(["a", "b"], arriving=True)
    assert change.gained
    # Every partition b wins is a's until a sees b: a hands each over.
    assert change.handed_by == dict.fromkeys(change.gained, "a")
    assert b.set_live([]).handed_by == {}  # alone: nobody to wait for


def test_a_leave_or_a_join_of_another_hands_nothing_over() -> None:
    # Rendezvous ranks two instances alike whoever else is alive: a partition an instance
    # gains on a leave belonged to the one that left, and a join gains it nothing.
    b = owner("b")
    take(b, ["a", "b", "c"])
    left = b.leave("c")
    assert left.gained
    assert left.handed_by == {}
    assert b.join("d").handed_by == {}
    # Starting anew (arriving) among live instances, b is handed its partitions by them.
    fresh = owner("b")
    arrived = fresh.set_live(["a", "b", "d"], arriving=True)
    assert set(arrived.handed_by.values()) <= {"a", "d"}
    assert sorted(arrived.handed_by) == arrived.gained

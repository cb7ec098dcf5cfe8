"""Memory-only hand-overs: the store's shelf carries a moved session to its new owner.

Real session tables and memory-only stores, one per "instance"; the records go from one to
the other as the checkpoint query carries them (``to_bytes`` and ``offer``). The reference is
one table that never handed anything over.
"""

from __future__ import annotations

from lessmap.runtime.record import SessionRecord
from lessmap.runtime.sessions import commit_checkpoints
from lessmap.runtime.shelf import MemoryShelf
from lessmap.runtime.store import CheckpointStore
from tests.service.durable_helpers import (
    FLEET,
    FRAMES,
    REFERENCE,
    ROBOT,
    errors,
    feed,
    make_table,
    transitions,
)


def record(seq: int, epoch: int = 1, robot: str = ROBOT) -> SessionRecord:
    return SessionRecord(
        fleet=FLEET,
        robot=robot,
        session="s1",
        status="open",
        last_seq=seq,
        meta={"epoch": epoch},
        snapshot=b"x",
        updated_s=0.0,
    )


def test_the_shelf_keeps_the_newest_record_of_each_robot_for_a_while() -> None:
    now = [0.0]
    shelf = MemoryShelf(keep_s=10.0, clock=lambda: now[0])
    shelf.put(record(5))
    assert not shelf.offer(record(4))  # older than the held one
    assert shelf.offer(record(7))
    assert shelf.offer(record(2, epoch=2))  # a later epoch wins whatever its seq
    assert shelf.get((FLEET, ROBOT)) == record(2, epoch=2)
    shelf.put(record(1, robot="other"))
    assert sorted(r.robot for r in shelf.where(lambda _f, _r: True)) == ["other", ROBOT]
    shelf.drop_where(lambda _f, r: r == "other")
    assert [r.robot for r in shelf.where(lambda _f, _r: True)] == [ROBOT]
    now[0] = 10.5
    assert shelf.get((FLEET, ROBOT)) is None  # kept keep_s at most
    assert len(shelf) == 0


def test_a_memory_only_store_saves_to_its_shelf_and_nowhere_else() -> None:
    store = CheckpointStore(None)
    assert store.shelf is not None
    assert not store.durable
    store.save(record(3))
    assert store.load((FLEET, ROBOT)) == record(3)
    assert store.records_where(lambda _f, r: r == ROBOT) == [record(3)]
    assert store.records() == []  # nothing written: there is no file
    store.delete((FLEET, ROBOT))
    assert store.load((FLEET, ROBOT)) is None


def test_a_session_handed_over_without_a_file_resumes_exactly_at_its_new_owner() -> None:
    half = len(FRAMES) // 2
    former_store, taker_store = CheckpointStore(None), CheckpointStore(None)
    former = make_table(former_store)
    first = feed(former, FRAMES[:half])
    handed = former.hand_over(lambda _f, _r: True, 1.0)
    assert handed.evicted == 1
    assert len(former) == 0
    commit_checkpoints(handed, former_store)
    # the new owner's checkpoint query: the former answers from its shelf, over the wire
    [answer] = former_store.records_where(lambda _f, _r: True)
    assert taker_store.offer(SessionRecord.from_bytes(answer.to_bytes()))
    taker = make_table(taker_store)
    assert not taker.is_news(FLEET, ROBOT, FRAMES[half - 1])  # applied by the former owner
    assert taker.is_news(FLEET, ROBOT, FRAMES[half])
    second = feed(taker, FRAMES[half:])
    assert len(second[0].resumed) == 1
    assert not errors(second)  # no SEQ_GAP: the session went on where it was
    assert transitions(first) + transitions(second) == REFERENCE
    assert taker_store.load((FLEET, ROBOT)) is None  # resumed: the shelf holds it no more


def test_without_the_record_the_new_owner_starts_afresh_as_before() -> None:
    half = len(FRAMES) // 2
    former = make_table(CheckpointStore(None))
    feed(former, FRAMES[:half])
    former.hand_over(lambda _f, _r: True, 1.0)
    taker = make_table(CheckpointStore(None))  # the record never came (the former died)
    second = feed(taker, FRAMES[half:])
    assert not second[0].resumed
    assert "SEQ_GAP" in {code.name for code in errors(second)}

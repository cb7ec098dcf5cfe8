"""The SQLite checkpoint store: reads during writes, queries, damaged files, WAL, retention."""

from __future__ import annotations

import sqlite3
import threading
import time
from typing import TYPE_CHECKING, Any

from lessmap.runtime.record import SessionRecord
from lessmap.runtime.store import STORE_FILE, CheckpointStore
from lessmap_schemas.errors import ErrorCode
from tests.service.durable_helpers import (
    FLEET,
    FRAMES,
    REFERENCE,
    ROBOT,
    SESSION,
    feed,
    make_table,
    open_store,
    transitions,
)

if TYPE_CHECKING:
    from pathlib import Path


def test_a_record_being_written_is_what_load_returns(tmp_path: Path) -> None:
    # Between the writer taking a batch and committing it, the record is in neither the
    # pending map nor the file: load must still return it, not the file's older row.
    gate, taken = threading.Event(), threading.Event()

    class SlowStore(CheckpointStore):
        def _commit(self, batch: Any) -> None:
            taken.set()
            gate.wait(10.0)
            super()._commit(batch)

    store = SlowStore(tmp_path)
    store.open()

    def record(last_seq: int) -> SessionRecord:
        return SessionRecord(
            fleet=FLEET,
            robot=ROBOT,
            session=SESSION,
            status="open",
            last_seq=last_seq,
            meta={},
            snapshot=b"x",
            updated_s=time.time() + last_seq,
        )

    gate.set()  # the first batch goes through
    store.save(record(10))
    assert store.flush()
    gate.clear()
    taken.clear()
    store.save(record(20))
    try:
        assert taken.wait(10.0)
        loaded = store.load((FLEET, ROBOT))
        assert loaded is not None
        assert loaded.last_seq == 20
        assert [r.last_seq for r in store.records_where(lambda *_: True)] == [20]
        assert store.robots_where(lambda *_: True) == [(FLEET, ROBOT)]
    finally:
        gate.set()
    assert store.flush()
    store.close()


def test_robots_where_reads_only_thenamed_fleet_and_robot(tmp_path: Path) -> None:
    from lessmap.runtime.queries import named_fleet_and_robot

    store = open_store(tmp_path)
    for fleet, robot in [("f1", "a"), ("f1", "b"), ("f2", "a")]:
        store.save(
            SessionRecord(
                fleet=fleet,
                robot=robot,
                session=SESSION,
                status="evicted",
                last_seq=1,
                meta={},
                snapshot=b"x",
                updated_s=time.time(),
            )
        )
    assert store.flush()
    every = store.robots_where(lambda *_: True)
    assert every == [("f1", "a"), ("f1", "b"), ("f2", "a")]
    assert store.robots_where(lambda *_: True, fleet="f1") == [("f1", "a"), ("f1", "b")]
    assert store.robots_where(lambda *_: True, fleet="f1", robot="b") == [("f1", "b")]
    assert store.robots_where(lambda _f, r: r == "a", fleet="f1") == [("f1", "a")]
    store.close()
    # A query's selector names a fleet and a robot only where it holds no wildcard.
    assert named_fleet_and_robot("lessmap/v4/f1/b/state") == ("f1", "b")
    assert named_fleet_and_robot("lessmap/v4/f1/*/areas") == ("f1", None)
    assert named_fleet_and_robot("lessmap/v4/*/b/state") == (None, None)
    assert named_fleet_and_robot("lessmap/v4/**") == (None, None)


def test_a_corrupt_store_file_is_moved_aside(tmp_path: Path) -> None:
    (tmp_path / STORE_FILE).write_bytes(b"this is not a database" * 100)
    store = open_store(tmp_path)
    assert len(store.problems) == 1
    assert "unreadable" in store.problems[0]
    assert list(tmp_path.glob(f"{STORE_FILE}.corrupt-*"))
    table = make_table(store)
    assert transitions(feed(table, FRAMES)) == REFERENCE
    store.close()


def test_a_truncated_store_file_is_moved_aside(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = make_table(store)
    feed(table, FRAMES[:100])
    table.close_all("shutdown")
    store.close()
    data = (tmp_path / STORE_FILE).read_bytes()
    (tmp_path / STORE_FILE).write_bytes(data[: len(data) // 3])
    store = open_store(tmp_path)
    table = make_table(store)
    feed(table, FRAMES[100:])  # nothing to resume from: the frames start a fresh graph
    assert len(store.problems) == 1
    state = table.state(FLEET, ROBOT)
    assert state is not None
    assert state.frames_applied == len(FRAMES) - 100
    store.close()


def test_an_unreadable_checkpoint_costs_only_its_session(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    store.save(
        SessionRecord(
            fleet=FLEET,
            robot=ROBOT,
            session=SESSION,
            status="open",
            last_seq=5,
            meta={},
            snapshot=b"garbage",
            updated_s=0.0,
        )
    )
    table = make_table(store)
    out = table.handle_batch([(FLEET, ROBOT, FRAMES[6]), (FLEET, "other", FRAMES[0])], 0.0)
    internal = [r for r in out.rejections if r.code is ErrorCode.INTERNAL]
    assert [(r.robot, "checkpoint unreadable" in r.detail) for r in internal] == [(ROBOT, True)]
    other = table.state(FLEET, "other")
    mine = table.state(FLEET, ROBOT)
    assert other is not None
    assert mine is not None
    assert other.frames_applied == 1
    assert mine.frames_applied == 1  # started fresh at the frame that found the damage
    store.close()


def test_records_survive_in_sqlite_with_wal(tmp_path: Path) -> None:
    store = open_store(tmp_path)
    table = make_table(store, every=10)
    feed(table, FRAMES[:35])
    assert store.flush()
    with sqlite3.connect(tmp_path / STORE_FILE) as db:
        (mode,) = db.execute("PRAGMA journal_mode").fetchone()
        rows = db.execute("SELECT status, last_seq FROM sessions").fetchall()
    assert mode == "wal"
    assert rows == [("open", 29)]
    store.close()


def test_retention_and_size_bounds_drop_old_records(tmp_path: Path) -> None:
    clock = [1000.0]
    store = CheckpointStore(tmp_path, retention_s=50.0, clock=lambda: clock[0])
    store.open()
    for index in range(3):
        store.save(
            SessionRecord(
                fleet=FLEET,
                robot=f"r{index}",
                session=SESSION,
                status="evicted",
                last_seq=1,
                meta={},
                snapshot=b"x",
                updated_s=900.0 + 100 * index,  # 900, 1000, 1100
            )
        )
    assert store.flush()
    clock[0] = 2000.0 + 1100.0  # force a prune pass at the next write
    store.save(
        SessionRecord(
            fleet=FLEET,
            robot="fresh",
            session=SESSION,
            status="open",
            last_seq=1,
            meta={},
            snapshot=b"x",
            updated_s=clock[0],
        )
    )
    assert store.flush()
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and len(store.records()) > 1:
        time.sleep(0.02)
    assert [r.robot for r in store.records()] == ["fresh"]
    store.close()

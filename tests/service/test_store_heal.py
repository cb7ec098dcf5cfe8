"""The state store loses durability and heals: failed writes retried, a lost file rebuilt."""

from __future__ import annotations

import sqlite3
import time
from typing import TYPE_CHECKING, Any

from lessmap.runtime.record import SessionRecord
from lessmap.runtime.store import STORE_FILE, CheckpointStore
from tests.conftest import wait_until

if TYPE_CHECKING:
    from pathlib import Path


def record(robot: str, last_seq: int) -> SessionRecord:
    return SessionRecord(
        fleet="f",
        robot=robot,
        session="s",
        status="open",
        last_seq=last_seq,
        meta={"epoch": 1},
        snapshot=b"x" * 64,
        updated_s=time.time(),
    )


def rows_in_file(path: Path) -> dict[str, int]:
    with sqlite3.connect(path) as db:
        return dict(db.execute("SELECT robot, last_seq FROM sessions"))


class FullDisk(CheckpointStore):
    """A store whose commits fail while ``full`` is set, as on a filesystem out of space."""

    full = False

    def _commit(self, batch: Any) -> None:
        if self.full:
            msg = "database or disk is full"
            error = sqlite3.OperationalError(msg)
            error.sqlite_errorname = "SQLITE_FULL"
            raise error
        super()._commit(batch)


def test_a_failed_write_is_retried_and_reported_lost_then_back(tmp_path: Path) -> None:
    store = FullDisk(tmp_path)
    store.open()
    try:
        store.save(record("a", 1))
        assert store.flush()
        store.full = True
        store.save(record("a", 2))
        wait_until(lambda: store.health.lost, 10.0, "the failed write noticed")
        store.save(record("b", 5))  # saved while lost: kept in memory, readable
        loaded = store.load(("f", "a"))
        assert loaded is not None
        assert loaded.last_seq == 2
        assert not store.flush(0.2)  # nothing reaches the file
        assert rows_in_file(tmp_path / STORE_FILE) == {"a": 1}
        store.full = False
        wait_until(lambda: not store.health.lost, 15.0, "the retry to succeed")
        assert store.flush()
        assert rows_in_file(tmp_path / STORE_FILE) == {"a": 2, "b": 5}
        changes = store.health.take_changes()
        assert [lost for lost, _detail in changes] == [True, False]
        assert "durability lost" in changes[0][1]
        assert "database or disk is full" in changes[0][1]
        assert "durability back" in changes[1][1]
        assert (store.health.losses, store.health.heals) == (1, 1)
    finally:
        store.close()


def test_a_deleted_store_file_is_rebuilt_with_what_the_old_one_held(tmp_path: Path) -> None:
    store = CheckpointStore(tmp_path)
    store.open()
    try:
        store.save(record("a", 1))
        store.save(record("b", 7))
        assert store.flush()
        for suffix in ("", "-wal", "-shm"):
            (tmp_path / (STORE_FILE + suffix)).unlink(missing_ok=True)
        wait_until(lambda: store.health.heals == 1, 15.0, "the deleted file to be rebuilt")
        store.save(record("a", 3))
        assert store.flush()
        # The old connection still read the deleted file: its rows were copied over.
        assert rows_in_file(tmp_path / STORE_FILE) == {"a": 3, "b": 7}
        changes = store.health.take_changes()
        assert [lost for lost, _detail in changes] == [True, False]
        assert "deleted" in changes[0][1]
    finally:
        store.close()


def test_a_store_file_overwritten_with_garbage_is_moved_aside_and_rebuilt(
    tmp_path: Path,
) -> None:
    store = CheckpointStore(tmp_path)
    store.open()
    try:
        store.save(record("a", 1))
        assert store.flush()
        path = tmp_path / STORE_FILE
        path.write_bytes(b"\xde\xad\xbe\xef" * 4096)  # same inode, not a database any more
        wait_until(lambda: store.health.heals == 1, 15.0, "the overwritten file to be rebuilt")
        store.save(record("a", 4))
        assert store.flush()
        assert rows_in_file(path)["a"] == 4
        assert any(".lost-" in p.name for p in tmp_path.iterdir())  # kept for the operator
        assert "overwritten" in store.health.take_changes()[0][1]
    finally:
        store.close()


def test_a_healthy_store_reports_nothing(tmp_path: Path) -> None:
    store = CheckpointStore(tmp_path)
    store.open()
    try:
        store.save(record("a", 1))
        assert store.flush()
        time.sleep(1.5)  # at least one look at the file
        assert store.health.take_changes() == []
        assert not store.health.lost
    finally:
        store.close()

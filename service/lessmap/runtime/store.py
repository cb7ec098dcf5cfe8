"""Session checkpoints in an embedded SQLite database (WAL), written off the receive path.

Rules of this file:

1. One row per robot (fleet, robot): the checkpoint of its current session (``open``), of a
   session evicted from memory while idle (``evicted``), or the final record of a closed one
   (``closed``, no partitioner state). A newer session of the robot replaces the row.
2. ``save`` never blocks on the disk: it replaces the robot's pending record in a dict (the
   latest checkpoint wins, so the pending set is bounded by the number of robots) and wakes
   the writer thread, which commits everything pending in one transaction.
3. ``load`` sees what ``save`` gave, written or not (the pending dict first, then the file).
4. A store that cannot be opened or read is moved aside once (``<name>.corrupt-<stamp>``)
   and a fresh one is created; a write that fails is logged and the store goes memory-only.
   The service never dies because of its state directory.
5. Retention: rows not updated for ``retention_s`` are deleted, and while the file holds more
   than ``max_bytes`` the oldest rows of sessions no longer in memory go first.
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pathlib import Path

log = logging.getLogger(__name__)

RobotKey = tuple[str, str]  # (fleet, robot)

STORE_FILE = "sessions.sqlite3"
_SCHEMA_VERSION = 1
_PRUNE_EVERY_S = 30.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SessionRecord:
    """What the store keeps of one robot's session."""

    fleet: str
    robot: str
    session: str
    status: str  # "open" | "evicted" | "closed"
    last_seq: int | None  # highest seq received when the record was taken
    meta: dict[str, Any]  # counters, gap ranges, closed session ids, final state (JSON)
    snapshot: bytes | None  # lessmap.core.snapshot bytes; None once closed
    updated_s: float  # wall clock (time.time) of the record

    @property
    def key(self) -> RobotKey:
        """(fleet, robot)."""
        return (self.fleet, self.robot)


class StoreError(RuntimeError):
    """The state directory cannot hold a store at all (not a folder, not writable)."""


class CheckpointStore:
    """Session records in ``<state_dir>/sessions.sqlite3``; ``state_dir=None``: memory only."""

    def __init__(
        self,
        state_dir: Path | None,
        *,
        retention_s: float = 7 * 24 * 3600.0,
        max_bytes: int = 1 << 30,
        clock: Any = time.time,
    ) -> None:
        self.path = None if state_dir is None else state_dir / STORE_FILE
        self.retention_s = retention_s
        self.max_bytes = max_bytes
        self._clock = clock
        self._pending: dict[RobotKey, SessionRecord | None] = {}  # None: delete
        self._in_flight = False  # the writer holds a batch taken from _pending
        self._cond = threading.Condition()
        self._db_lock = threading.Lock()  # one connection, shared by the writer and readers
        self._db: sqlite3.Connection | None = None
        self._thread: threading.Thread | None = None
        self._stopping = False
        self._last_prune_s = 0.0
        self.problems: list[str] = []  # what went wrong on open, for the service to report
        self.writes = 0  # records committed (metric)
        self.write_seconds = 0.0

    @property
    def durable(self) -> bool:
        """True when records reach a file."""
        return self._db is not None

    # -- lifecycle ---------------------------------------------------------------------------

    def open(self) -> None:
        """Open (or create) the database and start the writer thread.

        A corrupt or unreadable file is moved aside and replaced by a new one; the reason is
        appended to ``problems``.

        Raises:
            StoreError: the state directory cannot be created or written at all.
        """
        if self.path is None:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            msg = f"state directory {self.path.parent}: {exc.strerror or exc}"
            raise StoreError(msg) from exc
        try:
            self._db = self._connect()
        except sqlite3.DatabaseError as exc:
            aside = self.path.with_name(f"{self.path.name}.corrupt-{int(self._clock())}")
            problem = f"state store {self.path} is unreadable ({exc}); moved to {aside.name}"
            self.problems.append(problem + ", starting with an empty store")
            log.error("%s; starting with an empty store", problem)
            for suffix in ("", "-wal", "-shm"):
                part = self.path.with_name(self.path.name + suffix)
                if part.exists():
                    part.replace(aside.with_name(aside.name + suffix))
            try:
                self._db = self._connect()
            except sqlite3.DatabaseError as again:
                msg = f"state store {self.path}: {again}"
                raise StoreError(msg) from again
        self._thread = threading.Thread(target=self._run, name="lessmap-store", daemon=True)
        self._thread.start()

    def _connect(self) -> sqlite3.Connection:
        assert self.path is not None
        db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=NORMAL")  # WAL: durable across a process crash
            db.execute(
                "CREATE TABLE IF NOT EXISTS sessions ("
                " fleet TEXT NOT NULL, robot TEXT NOT NULL, session TEXT NOT NULL,"
                " status TEXT NOT NULL, last_seq INTEGER, meta TEXT NOT NULL,"
                " snapshot BLOB, updated_s REAL NOT NULL, PRIMARY KEY (fleet, robot))"
            )
            db.execute("CREATE TABLE IF NOT EXISTS info (name TEXT PRIMARY KEY, value TEXT)")
            db.execute("INSERT OR IGNORE INTO info VALUES ('schema', ?)", (str(_SCHEMA_VERSION),))
            (version,) = db.execute("SELECT value FROM info WHERE name = 'schema'").fetchone()
            if version != str(_SCHEMA_VERSION):
                msg = f"store schema {version}, this version reads {_SCHEMA_VERSION}"
                raise sqlite3.DatabaseError(msg)
            (check,) = db.execute("PRAGMA quick_check").fetchone()
            if check != "ok":
                raise sqlite3.DatabaseError(check)
        except BaseException:
            db.close()
            raise
        return db

    def close(self, timeout_s: float = 10.0) -> None:
        """Write everything pending, stop the writer, close the file."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.warning("state store: pending checkpoints not written within %.1f s", timeout_s)
        with self._db_lock:
            if self._db is not None:
                self._db.close()
                self._db = None

    # -- records -----------------------------------------------------------------------------

    def save(self, record: SessionRecord) -> None:
        """Queue a record for writing (the robot's previous pending record is replaced)."""
        if self.path is None:
            return
        with self._cond:
            self._pending[record.key] = record
            self._cond.notify()

    def delete(self, key: RobotKey) -> None:
        """Queue the removal of a robot's record."""
        if self.path is None:
            return
        with self._cond:
            self._pending[key] = None
            self._cond.notify()

    def load(self, key: RobotKey) -> SessionRecord | None:
        """Return the robot's latest record, pending or written.

        Raises:
            sqlite3.DatabaseError: the file could not be read (the caller reports it and
                starts the session fresh).
        """
        with self._cond:
            if key in self._pending:
                return self._pending[key]
        with self._db_lock:
            if self._db is None:
                return None
            row = self._db.execute(
                "SELECT fleet, robot, session, status, last_seq, meta, snapshot, updated_s"
                " FROM sessions WHERE fleet = ? AND robot = ?",
                key,
            ).fetchone()
        return None if row is None else _record(row)

    def records(self) -> list[SessionRecord]:
        """Every written record (pending ones not included): for start-up and tests."""
        with self._db_lock:
            if self._db is None:
                return []
            rows = self._db.execute(
                "SELECT fleet, robot, session, status, last_seq, meta, snapshot, updated_s"
                " FROM sessions"
            ).fetchall()
        return [_record(row) for row in rows]

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Wait until everything saved so far is committed to the file; False on timeout."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while (self._pending or self._in_flight) and self._db is not None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.notify()
                self._cond.wait(min(remaining, 0.05))
        return True

    # -- writer thread -----------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._stopping:
                    self._cond.wait(timeout=_PRUNE_EVERY_S)
                    if not self._pending:
                        break
                batch, self._pending = self._pending, {}
                self._in_flight = bool(batch)
                stopping = self._stopping
            if batch:
                self._write(batch)
            # Drop the written records now: kept until the next round, a batch of evicted
            # sessions (their snapshots) would stay in memory while the writer waits.
            del batch
            with self._cond:
                self._in_flight = False
                self._cond.notify_all()  # flush() waiters
            now = self._clock()
            if now - self._last_prune_s >= _PRUNE_EVERY_S:
                self._last_prune_s = now
                self._prune(now)
            if stopping:
                with self._cond:
                    if not self._pending:
                        return

    def _write(self, batch: dict[RobotKey, SessionRecord | None]) -> None:
        started = time.perf_counter()
        rows = [
            (
                r.fleet,
                r.robot,
                r.session,
                r.status,
                r.last_seq,
                json.dumps(r.meta),
                r.snapshot,
                r.updated_s,
            )
            for r in batch.values()
            if r is not None
        ]
        gone = [key for key, r in batch.items() if r is None]
        try:
            with self._db_lock:
                if self._db is None:
                    return
                self._db.execute("BEGIN")
                self._db.executemany(
                    "INSERT OR REPLACE INTO sessions VALUES (?, ?, ?, ?, ?, ?, ?, ?)", rows
                )
                self._db.executemany("DELETE FROM sessions WHERE fleet = ? AND robot = ?", gone)
                self._db.execute("COMMIT")
        except sqlite3.Error as exc:
            log.error("state store %s: write failed (%s); continuing memory-only", self.path, exc)
            with self._db_lock:
                if self._db is not None:
                    self._db.close()
                    self._db = None
            return
        self.writes += len(batch)
        self.write_seconds += time.perf_counter() - started

    def _prune(self, now: float) -> None:
        try:
            with self._db_lock:
                if self._db is None:
                    return
                self._db.execute(
                    "DELETE FROM sessions WHERE updated_s < ?", (now - self.retention_s,)
                )
                while self._size_bytes() > self.max_bytes:
                    deleted = self._db.execute(
                        "DELETE FROM sessions WHERE rowid IN (SELECT rowid FROM sessions"
                        " WHERE status != 'open' ORDER BY updated_s LIMIT 64)"
                    ).rowcount
                    if not deleted:
                        log.warning(
                            "state store %s holds more than %d bytes of open sessions",
                            self.path,
                            self.max_bytes,
                        )
                        break
        except sqlite3.Error as exc:
            log.error("state store %s: pruning failed: %s", self.path, exc)

    def _size_bytes(self) -> int:
        assert self._db is not None
        (pages,) = self._db.execute("PRAGMA page_count").fetchone()
        (free,) = self._db.execute("PRAGMA freelist_count").fetchone()
        (size,) = self._db.execute("PRAGMA page_size").fetchone()
        return int((pages - free) * size)


def _record(row: tuple[Any, ...]) -> SessionRecord:
    fleet, robot, session, status, last_seq, meta, snapshot, updated_s = row
    return SessionRecord(
        fleet=fleet,
        robot=robot,
        session=session,
        status=status,
        last_seq=last_seq,
        meta=json.loads(meta),
        snapshot=snapshot,
        updated_s=updated_s,
    )

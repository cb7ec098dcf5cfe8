"""Session checkpoints in an embedded SQLite database (WAL), written off the receive path.

Rules of this file:

1. One row per robot (fleet, robot): the checkpoint of its current session (``open``), of a
   session evicted while idle (``evicted``), or the final record of a closed one
   (``closed``, no partitioner state). A newer session of the robot replaces the row.
2. ``save`` never blocks on the disk: it replaces the robot's pending record (the latest
   wins) and wakes the writer thread, which commits everything pending in one transaction.
3. ``load`` sees what ``save`` gave, written or not (the pending dict first, then the file).
4. A store that cannot be opened or read is moved aside and a fresh one is created. A write
   that fails loses durability: the records stay pending in memory and the writer retries
   with backoff; a file deleted, replaced or overwritten while open is noticed
   (``store_file.py``) and rebuilt. Each loss and each heal is counted and reported once
   (``take_changes``); ``heals`` tells the shards to checkpoint their sessions again.
   The service never dies of it.
5. Retention: rows not updated for ``retention_s`` are deleted, and while the file holds more
   than ``max_bytes`` the oldest rows of sessions no longer in memory go first.
6. Without a file (memory only) the records a hand-over saves go to a ``MemoryShelf``.
"""

from __future__ import annotations

import fcntl
import json
import logging
import sqlite3
import threading
import time
from typing import TYPE_CHECKING, Any, BinaryIO

from lessmap.runtime.memory import release_free_memory, trim_heap
from lessmap.runtime.record import RobotKey, SessionRecord
from lessmap.runtime.shelf import MemoryShelf
from lessmap.runtime.store_file import (
    CHECK_EVERY_S,
    StoreHealth,
    file_id,
    file_problem,
    move_aside,
    prune,
    reopen,
)

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

log = logging.getLogger(__name__)


STORE_FILE = "sessions.sqlite3"
LOCK_FILE = "instance.lock"
_SCHEMA_VERSION = 2  # 2: records carry the partition epoch (wire contract v2)
_PRUNE_EVERY_S = 30.0
_RELEASE_EVERY_S = 1.0  # memory given back at most this often (a full collection: milliseconds)
_TRIM_AFTER_RECORDS = 64  # evicted sessions written that call for a plain heap trim in between


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
        self.shelf = MemoryShelf() if self.path is None else None  # rule 6
        self.retention_s = retention_s
        self.max_bytes = max_bytes
        self._clock = clock
        self._pending: dict[RobotKey, SessionRecord | None] = {}  # None: delete
        self._writing: dict[RobotKey, SessionRecord | None] = {}  # the batch being written
        self._in_flight = False  # the writer holds a batch taken from _pending
        self._lock_file: BinaryIO | None = None
        # Memory release (``release_memory_soon``): batches taken and written by the writer,
        # and the number of written batches after which a requested release is due.
        self._batches_taken = 0
        self._batches_done = 0
        self._release_after: int | None = None
        self._last_release_s = float("-inf")
        self._evicted_since_trim = 0
        self._cond = threading.Condition()
        self._db_lock = threading.Lock()  # one connection, shared by the writer and readers
        self._db: sqlite3.Connection | None = None
        self._thread: threading.Thread | None = None
        self._stopping = False
        self._last_prune_s = 0.0
        self.problems: list[str] = []  # what went wrong on open, for the service to report
        self.writes = 0  # records committed (metric)
        self.write_seconds = 0.0
        self.health = StoreHealth(self.path)  # rule 4
        self._file_id: tuple[int, int] | None = None  # (device, inode) of the open file
        self._checked_s = 0.0

    @property
    def durable(self) -> bool:
        """True when a file is open (it may be refusing writes: ``health.lost``)."""
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
            self._lock_file = (self.path.parent / LOCK_FILE).open("a+b")
        except OSError as exc:
            msg = (
                f"state directory {self.path.parent}: {exc.strerror or exc} "
                "(give --state-dir a writable folder, or --memory-only)"
            )
            raise StoreError(msg) from exc
        try:
            # One instance per state directory: two would overwrite each other's rows.
            fcntl.flock(self._lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            self._lock_file.close()
            self._lock_file = None
            msg = (
                f"state directory {self.path.parent} is in use by another lessmap instance; "
                "give each instance its own --state-dir"
            )
            raise StoreError(msg) from exc
        try:
            self._db = self._connect()
        except sqlite3.DatabaseError as exc:
            aside = move_aside(self.path, f"corrupt-{int(self._clock())}")
            problem = f"state store {self.path} is unreadable ({exc}); moved to {aside}"
            self.problems.append(problem + ", starting with an empty store")
            log.error("%s; starting with an empty store", problem)
            try:
                self._db = self._connect()
            except sqlite3.DatabaseError as again:
                msg = f"state store {self.path}: {again} (give --state-dir another folder)"
                raise StoreError(msg) from again
        self._file_id = file_id(self.path)
        self._checked_s = time.monotonic()
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
        if self._lock_file is not None:
            self._lock_file.close()  # releases the flock
            self._lock_file = None

    # -- records -----------------------------------------------------------------------------

    def save(self, record: SessionRecord) -> None:
        """Queue a record for writing (the robot's previous pending record is replaced)."""
        if self.shelf is not None:
            self.shelf.put(record)
            return
        with self._cond:
            self._pending[record.key] = record
            self._cond.notify()

    def delete(self, key: RobotKey) -> None:
        """Queue the removal of a robot's record."""
        if self.shelf is not None:
            self.shelf.drop(key)
            return
        with self._cond:
            self._pending[key] = None
            self._cond.notify()

    def release_memory_soon(self) -> None:
        """Give the memory of sessions that left back to the OS, once their records are written.

        Called after sessions were evicted or handed over. Their records are pending here and
        the writer frees them (snapshots, keys, rows) only after writing them: the writer
        releases (``memory.release_free_memory`` and SQLite's page cache) after the batch that
        holds what is pending now, at most once every ``_RELEASE_EVERY_S``; a request inside
        that time waits for it, none is dropped. Without a writer (memory-only) the calling
        thread releases at once.
        """
        if self._thread is None:
            release_free_memory()
            return
        with self._cond:
            due = self._batches_taken + (1 if self._pending else 0)
            self._release_after = max(due, self._release_after or 0)
            self._cond.notify()

    def load(self, key: RobotKey) -> SessionRecord | None:
        """Return the robot's latest record, pending or written.

        Raises:
            sqlite3.DatabaseError: the file could not be read (the caller reports it and
                starts the session fresh).
        """
        if self.shelf is not None:
            return self.shelf.get(key)
        with self._cond:
            if key in self._pending:
                return self._pending[key]
            if key in self._writing:  # taken by the writer, not committed yet
                return self._writing[key]
        with self._db_lock:
            if self._db is None:
                return None
            row = self._db.execute(
                "SELECT fleet, robot, session, status, last_seq, meta, snapshot, updated_s"
                " FROM sessions WHERE fleet = ? AND robot = ?",
                key,
            ).fetchone()
        return None if row is None else _record(row)

    def resumed(self, key: RobotKey) -> None:
        """A session ``load`` gave back runs again: the shelf forgets it (a file keeps it)."""
        if self.shelf is not None:
            self.shelf.drop(key)

    def offer(self, record: SessionRecord) -> bool:
        """Save a record shipped by another instance if it is newer than what is held.

        Reads the file (call it off the receive path). Returns True when saved.
        """
        if self.shelf is not None:
            return self.shelf.offer(record)
        try:
            current = self.load(record.key)
        except sqlite3.Error:
            current = None
        if not record.newer_than(current):
            return False
        with self._cond:
            pending = self._pending.get(record.key)
            if pending is not None and not record.newer_than(pending):
                return False
            self._pending[record.key] = record
            self._cond.notify()
        return True

    def robots_where(
        self,
        keep: Callable[[str, str], bool],
        *,
        fleet: str | None = None,
        robot: str | None = None,
    ) -> list[RobotKey]:
        """Every robot with a record (pending or written) for which ``keep`` is True.

        Names only: what a query needs to find the robots it must answer for that are not
        in memory (closed before a restart, evicted, or received from another instance).
        ``fleet`` (and ``robot``) narrow the file's read to that fleet (robot) by its
        primary key: a robot polling its own state does not scan every record.
        """
        with self._cond:
            recent = self._writing | self._pending  # the pending record is the newer
            found = {k for k, r in recent.items() if r is not None and keep(*k)}
            gone = {k for k, r in recent.items() if r is None}
        args: tuple[str, ...] = ()
        if fleet is None:
            sql = "SELECT fleet, robot FROM sessions"
        elif robot is None:
            sql, args = "SELECT fleet, robot FROM sessions WHERE fleet = ?", (fleet,)
        else:
            sql = "SELECT fleet, robot FROM sessions WHERE fleet = ? AND robot = ?"
            args = (fleet, robot)
        with self._db_lock:
            if self._db is not None:
                found.update(
                    (f, r)
                    for f, r in self._db.execute(sql, args)
                    if (f, r) not in gone and keep(f, r)
                )
        return sorted(found)

    def records_where(self, keep: Callable[[str, str], bool]) -> list[SessionRecord]:
        """The latest record (pending or written) of every robot for which ``keep`` is True."""
        if self.shelf is not None:
            return self.shelf.where(keep)
        with self._cond:
            # The batch being written first, the pending records over it (they are newer).
            pending = {k: r for k, r in (self._writing | self._pending).items() if keep(*k)}
        with self._db_lock:
            if self._db is None:
                names = []
            else:
                names = [
                    (fleet, robot)
                    for fleet, robot in self._db.execute("SELECT fleet, robot FROM sessions")
                    if keep(fleet, robot) and (fleet, robot) not in pending
                ]
        out = [r for r in pending.values() if r is not None]
        for key in names:
            record = self.load(key)
            if record is not None:
                out.append(record)
        return out

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
        """Wait until everything saved so far is committed to the file.

        False on timeout, or at once while durability is lost (``health.lost``).
        """
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while (self._pending or self._in_flight) and self._db is not None:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self.health.lost:
                    return False
                self._cond.notify()
                self._cond.wait(min(remaining, 0.05))
            return not (self.health.lost and self._pending)

    # -- writer thread -----------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                health = self.health
                if not self._stopping and (
                    not self._pending or health.backing_off(time.monotonic())
                ):
                    self._cond.wait(timeout=self._idle_wait_s())
                stopping = self._stopping
                retry = health.lost and (stopping or not health.backing_off(time.monotonic()))
                batch: dict[RobotKey, SessionRecord | None] = {}
                if self._pending and (not health.lost or retry):
                    batch, self._pending = self._pending, {}
                    # Readable until committed: ``load`` must never fall back to an older row.
                    self._writing = batch
                    self._in_flight = True
                self._batches_taken += 1
            if not health.lost:
                self._watch_file(before_write=bool(batch))
                retry = health.lost  # the file is gone: rebuilt at once, the batch with it
            if retry:
                self._retry(batch)
            elif batch:
                self._write(batch)
            # Drop the written records now: kept until the next round, a batch of evicted
            # sessions (their snapshots) would stay in memory while the writer waits.
            self._evicted_since_trim += sum(
                1 for r in batch.values() if r is not None and r.status == "evicted"
            )
            del batch
            with self._cond:
                self._writing = {}
                self._batches_done += 1
                self._in_flight = False
                self._cond.notify_all()  # flush() waiters
                release = self._release_due()
            if release:
                # After the write: the records of the sessions that left are freed only now.
                self._shrink_cache()
                release_free_memory()
                self._last_release_s = time.monotonic()
                self._evicted_since_trim = 0
            elif self._evicted_since_trim >= _TRIM_AFTER_RECORDS:
                # Between two releases (an eviction wave): the cheap part, so the process
                # does not grow by a second's worth of evicted snapshots.
                trim_heap()
                self._evicted_since_trim = 0
            now = self._clock()
            if now - self._last_prune_s >= _PRUNE_EVERY_S and not health.lost:
                self._last_prune_s = now
                self._prune(now)
            if stopping:
                with self._cond:
                    if not self._pending:
                        return
                    if health.lost:
                        log.error(
                            "state store %s: %d checkpoint(s) not written at the stop (%s)",
                            self.path,
                            len(self._pending),
                            health.lost_reason,
                        )
                        return

    def _release_due(self) -> bool:
        """True (and the request is taken) when a requested release may run now (``_cond``)."""
        if self._release_after is None or self._batches_done < self._release_after:
            return False
        if time.monotonic() - self._last_release_s < _RELEASE_EVERY_S:
            return False
        self._release_after = None
        return True

    def _idle_wait_s(self) -> float:
        """How long the idle writer may wait: a due release, a retry, or a look at the file."""
        now = time.monotonic()
        wait_s = CHECK_EVERY_S
        if self.health.lost:
            wait_s = self.health.retry_at_s - now
        if self._release_after is not None and self._batches_done >= self._release_after:
            wait_s = min(wait_s, self._last_release_s + _RELEASE_EVERY_S - now)
        return max(0.0, wait_s)

    def _shrink_cache(self) -> None:
        """Free SQLite's page cache (the file's pages are read back from the OS on demand).

        The cache grows with the file up to ``cache_size`` (2 MiB): read and written while
        thousands of sessions came and went, its ~460 pages ended up spread over the heap
        among the freed sessions and kept ~2 MiB of it resident (docs/BENCHMARKS.md).
        """
        with self._db_lock:
            if self._db is None:
                return
            try:
                self._db.execute("PRAGMA shrink_memory")
            except sqlite3.Error as exc:
                log.warning("state store %s: could not shrink the cache: %s", self.path, exc)

    def _write(self, batch: dict[RobotKey, SessionRecord | None]) -> bool:
        """Commit a batch; on failure durability is lost and the batch waits for a retry."""
        try:
            self._commit(batch)
        except (sqlite3.Error, OSError) as exc:
            self._lose(f"write failed ({exc})", batch)
            if getattr(exc, "sqlite_errorname", "") != "SQLITE_FULL":
                self._close_db()  # the retry opens the file again (SQLite keeps a full disk's)
            return False
        return True

    def _commit(self, batch: dict[RobotKey, SessionRecord | None]) -> None:
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
        with self._db_lock:
            db = self._db
            if db is None:
                msg = "no open file"
                raise sqlite3.OperationalError(msg)
            try:
                db.execute("BEGIN")
                if not batch:  # a probe: something must reach the file
                    db.execute("INSERT OR REPLACE INTO info VALUES ('probed_s', ?)", (time.time(),))
                db.executemany(
                    "INSERT OR REPLACE INTO sessions VALUES (?, ?, ?, ?, ?, ?, ?, ?)", rows
                )
                db.executemany("DELETE FROM sessions WHERE fleet = ? AND robot = ?", gone)
                db.execute("COMMIT")
            except sqlite3.Error:
                if db.in_transaction:
                    db.execute("ROLLBACK")
                raise
        self.writes += len(batch)
        self.write_seconds += time.perf_counter() - started

    # -- durability: lost, retried, back (rule 4) --------------------------------------------

    def _watch_file(self, *, before_write: bool) -> None:
        """Lose durability when the open file was deleted, replaced or overwritten.

        Before every write (a record written to a lost file is lost with it) and at least
        every ``CHECK_EVERY_S``.
        """
        now = time.monotonic()
        if self.path is None or self._db is None:
            return
        if not before_write and now - self._checked_s < CHECK_EVERY_S:
            return
        self._checked_s = now
        problem = file_problem(self.path, self._file_id)
        if problem is not None:
            self._lose(problem, {}, now=True)  # rebuilt at once: nothing to wait for

    def _lose(
        self, reason: str, batch: dict[RobotKey, SessionRecord | None], *, now: bool = False
    ) -> None:
        """Keep a batch that did not reach the file pending; the next retry is scheduled."""
        with self._cond:
            self._pending = batch | self._pending  # records saved meanwhile are newer
        self.health.lose(reason, time.monotonic(), retry_now=now)

    def _retry(self, batch: dict[RobotKey, SessionRecord | None]) -> None:
        """Open a healthy file (rebuilt if it is gone or damaged), then write what is pending."""
        assert self.path is not None
        try:
            problem = file_problem(self.path, self._file_id) if self._db is not None else None
            if self._db is None or problem is not None:
                with self._db_lock:
                    old, self._db = self._db, None
                db = reopen(self.path, old, problem, self._connect, int(self._clock()))
                with self._db_lock:
                    self._db = db
                self._file_id = file_id(self.path)
                self._checked_s = time.monotonic()
        except (sqlite3.Error, OSError) as exc:
            self._lose(f"the file cannot be opened again ({exc})", batch)
            return
        # The batch itself is the probe: a full disk may take a small write and not it.
        if self._write(batch):
            self.health.heal(time.monotonic())

    def _close_db(self) -> None:
        with self._db_lock:
            db, self._db = self._db, None
        if db is not None:
            try:
                db.close()
            except sqlite3.Error as exc:
                log.debug("state store %s: closing a failed file: %s", self.path, exc)

    def _prune(self, now: float) -> None:
        try:
            with self._db_lock:
                if self._db is not None:
                    prune(self._db, now - self.retention_s, self.max_bytes, self.path)
        except sqlite3.Error as exc:
            log.error("state store %s: pruning failed: %s", self.path, exc)


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

"""The state store's file on disk: is it still the one the store opened, and readable?

The store keeps one SQLite connection open for its whole life. In WAL mode SQLite goes on
writing to a file that was deleted or replaced under it (the old inode lives on until the
connection closes) and reads garbage written over it only when a page leaves its cache. So
the store asks ``file_problem`` before it writes and at least every ``CHECK_EVERY_S``: the
path's (device, inode) against the one it opened, and the SQLite header.

What an old connection can still read (a deleted or replaced file) is ``salvage``d into the
new file; the rest is rebuilt from memory by checkpointing every open session again.
``StoreHealth`` holds whether records reach the file, the retry schedule and the changes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sqlite3
import threading
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

log = logging.getLogger(__name__)

CHECK_EVERY_S = 1.0  # an idle store looks at its file at least this often
RETRY_FIRST_S = 0.5  # after a failed write, the first retry comes this much later
RETRY_MAX_S = 5.0  # and the wait doubles up to this
SQLITE_MAGIC = b"SQLite format 3\x00"  # the first 16 bytes of every SQLite database file
PARTS = ("", "-wal", "-shm")  # the database and the files SQLite keeps beside it

FileId = tuple[int, int]  # (st_dev, st_ino)


def file_id(path: Path) -> FileId | None:
    """The (device, inode) of the file at ``path``, or None when there is none."""
    try:
        stat = os.stat(path)
    except FileNotFoundError:
        return None
    return (stat.st_dev, stat.st_ino)


def file_problem(path: Path, opened: FileId | None) -> str | None:
    """Why the file at ``path`` is no longer the database the store opened; None if it is."""
    try:
        found = file_id(path)
        if found is None:
            return "the file was deleted"
        if opened is not None and found != opened:
            return "the file was replaced by another one"
        with path.open("rb") as file:
            head = file.read(len(SQLITE_MAGIC))
    except OSError as exc:
        return f"the file cannot be read ({exc.strerror or exc})"
    # A database SQLite created holds its header from the first statement on (WAL mode
    # writes it), so a short or foreign head means someone wrote over it.
    if head != SQLITE_MAGIC:
        return "the file was overwritten (no SQLite header)"
    return None


def move_aside(path: Path, tag: str) -> str | None:
    """Rename the database and its companion files to ``<name>.<tag>*``; the new name, if any."""
    moved = None
    for suffix in PARTS:
        part = path.with_name(path.name + suffix)
        if part.exists():
            aside = path.with_name(f"{path.name}.{tag}{suffix}")
            part.replace(aside)
            moved = moved or aside.name
    return moved


def salvage(db: sqlite3.Connection) -> list[tuple[Any, ...]]:
    """Every session row an old connection can still read ([] when it reads garbage)."""
    try:
        return list(
            db.execute(
                "SELECT fleet, robot, session, status, last_seq, meta, snapshot, updated_s"
                " FROM sessions"
            )
        )
    except sqlite3.Error:
        return []


def prune(db: sqlite3.Connection, older_than_s: float, max_bytes: int, path: Path | None) -> None:
    """Retention: delete rows not updated since ``older_than_s``.

    Then, while the file holds more than ``max_bytes``, the oldest rows of sessions that are
    not open.
    """
    db.execute("DELETE FROM sessions WHERE updated_s < ?", (older_than_s,))
    while size_bytes(db) > max_bytes:
        deleted = db.execute(
            "DELETE FROM sessions WHERE rowid IN (SELECT rowid FROM sessions"
            " WHERE status != 'open' ORDER BY updated_s LIMIT 64)"
        ).rowcount
        if not deleted:
            log.warning("state store %s holds more than %d bytes of open sessions", path, max_bytes)
            return


def size_bytes(db: sqlite3.Connection) -> int:
    """Bytes the database's used pages take."""
    (pages,) = db.execute("PRAGMA page_count").fetchone()
    (free,) = db.execute("PRAGMA freelist_count").fetchone()
    (size,) = db.execute("PRAGMA page_size").fetchone()
    return int((pages - free) * size)


def reopen(
    path: Path,
    old: sqlite3.Connection | None,
    problem: str | None,
    connect: Callable[[], sqlite3.Connection],
    stamp: int,
) -> sqlite3.Connection:
    """Open the store's path again, the old connection closed; a file not ours is moved aside.

    With a ``problem`` (the file was deleted, replaced or overwritten), what ``old`` can still
    read is copied into the new file. Raises what ``connect`` raises on a second failure.
    """
    rows = [] if old is None or problem is None else salvage(old)
    if old is not None:
        with contextlib.suppress(sqlite3.Error):  # a lost file: nothing more to save from it
            old.close()
    if problem is not None:
        move_aside(path, f"lost-{stamp}")
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        db = connect()
    except sqlite3.DatabaseError:  # unreadable: kept for the operator, a new file
        move_aside(path, f"corrupt-{stamp}")
        db = connect()
    # What the old file held; the pending records, written next, are newer.
    db.executemany("INSERT OR IGNORE INTO sessions VALUES (?, ?, ?, ?, ?, ?, ?, ?)", rows)
    return db


class StoreHealth:
    """Whether records reach the file, when to retry, and the changes still to report.

    Written by the store's writer thread; ``take_changes`` is for whoever reports them.
    """

    def __init__(self, path: Path | None) -> None:
        self._path = path
        self._lock = threading.Lock()
        self.lost_reason: str | None = None  # None: records reach the file
        self.losses = 0
        self.heals = 0  # a change tells the shards to checkpoint their sessions again
        self.retry_at_s = 0.0
        self._retry_wait_s = RETRY_FIRST_S
        self._lost_since_s = 0.0
        self._changes: list[tuple[bool, str]] = []

    @property
    def lost(self) -> bool:
        """True while records do not reach the file."""
        return self.lost_reason is not None

    def backing_off(self, now_s: float) -> bool:
        """True while durability is lost and the next retry is not due yet."""
        return self.lost_reason is not None and now_s < self.retry_at_s

    def lose(self, reason: str, now_s: float, *, retry_now: bool = False) -> None:
        """Note a failure: the first one of a loss is logged and reported, retries back off."""
        with self._lock:
            if self.lost_reason is None:
                self.lost_reason = reason
                self.losses += 1
                self._lost_since_s = now_s
                self._retry_wait_s = RETRY_FIRST_S
                detail = (
                    f"state store {self._path}: durability lost, {reason}; checkpoints are "
                    "kept in memory and written once the store heals"
                )
                self._changes.append((True, detail))
                log.error("%s", detail)
            else:
                self._retry_wait_s = min(2 * self._retry_wait_s, RETRY_MAX_S)
            self.retry_at_s = now_s if retry_now else now_s + self._retry_wait_s

    def heal(self, now_s: float) -> None:
        """Note that records reach the file again (logged and reported once)."""
        with self._lock:
            if self.lost_reason is None:
                return
            detail = (
                f"state store {self._path}: durability back after "
                f"{now_s - self._lost_since_s:.1f} s ({self.lost_reason}); every open "
                "session is checkpointed again"
            )
            self.lost_reason = None
            self.heals += 1
            self._changes.append((False, detail))
        log.warning("%s", detail)

    def take_changes(self) -> list[tuple[bool, str]]:
        """The changes since the last call, oldest first: (lost?, what happened)."""
        with self._lock:
            changes, self._changes = self._changes, []
        return changes

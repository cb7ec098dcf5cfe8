"""A shard's bounded inbound queue: what the receive path hands on, for the worker to take.

Invariants:

1. ``offer`` never blocks: an item past the bounds (messages, bytes, and per robot key a
   quarter of each, so one robot cannot fill it for the others) is refused and the caller
   reports it; the end of a catch-up query is always taken (one per query, a few bytes), so
   a full queue cannot leave a hold waiting.
2. An item holds its share of the bounds from ``offer`` until the worker gives it back
   after handling it (in the queue or in a robot's lane: ``depth`` counts both).
3. Once ``stop`` was called, new samples are refused.
4. A catch-up's end is taken after its replies (one FIFO): ``cache_replies`` keeps that order.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import TYPE_CHECKING, NamedTuple

from lessmap_schemas.codec import decode_inbound
from lessmap_schemas.errors import WireError
from lessmap_schemas.keys import parse_robot_key
from lessmap_schemas.messages import Frame

if TYPE_CHECKING:
    from collections.abc import Iterable

    from lessmap_schemas.errors import ErrorCode
    from lessmap_schemas.limits import WireLimits

_ROBOT_SHARE = 4  # one robot may hold at most 1/_ROBOT_SHARE of the queue (messages, bytes)
_NOTES_KEPT = 10_000  # refusals waiting for the worker to report them

LIVE = 0  # a sample of the frames subscriber
RECOVERED = 1  # a reply of a robot's publication cache to a catch-up query
CATCHUP_DONE = 2  # the end of a catch-up query; the payload is the session id (UTF-8)
PROBE = 3  # a robot cache's newest frame, asked when a partition is taken: applied if news


class Inbound(NamedTuple):
    """One raw sample as it was received (a tuple: built once per sample, cheaply)."""

    received_s: float  # time.monotonic() at receipt
    key: str
    payload: bytes
    kind: int = LIVE


class InboundQueue:
    """The bounded FIFO between the receive path and one shard's worker."""

    def __init__(self, depth: int, max_bytes: int) -> None:
        self.depth_limit = depth
        self._max_bytes = max_bytes
        self.cond = threading.Condition()  # guards the queue; the worker waits on it
        self.queue: deque[Inbound] = deque()
        self._held = 0  # items taken and not given back (invariant 2), and their bytes
        self._bytes = 0
        self._per_key: dict[str, list[int]] = {}
        self.stopping = False
        # Refusals decided on the receive path, reported by the worker; deque appends are
        # atomic, and maxlen bounds a flood.
        self.notes: deque[tuple[str, ErrorCode, str]] = deque(maxlen=_NOTES_KEPT)

    def offer(self, item: Inbound) -> bool:
        """Enqueue an item without blocking; False when refused (invariant 1)."""
        with self.cond:
            taken = self._admit(item)
            if taken:
                self.cond.notify()
        return taken

    def offer_many(self, items: list[Inbound]) -> list[Inbound]:
        """Enqueue items in order, as ``offer`` each, with one wake-up; return those refused."""
        with self.cond:
            admit = self._admit
            refused = [item for item in items if not admit(item)]
            if len(refused) < len(items):
                self.cond.notify()
        return refused

    def _admit(self, item: Inbound) -> bool:
        """Append one item if the bounds allow it (caller holds ``cond``)."""
        size = len(item.payload)
        key = item.key
        load = self._per_key.get(key)
        if item.kind != CATCHUP_DONE and (
            self.stopping
            or self._held >= self.depth_limit
            or self._bytes + size > self._max_bytes
            or (
                load is not None
                and (
                    load[0] * _ROBOT_SHARE >= self.depth_limit
                    or (load[1] + size) * _ROBOT_SHARE > self._max_bytes
                )
            )
        ):
            return False
        if load is None:
            self._per_key[key] = [1, size]
        else:
            load[0] += 1
            load[1] += size
        self.queue.append(item)
        self._held += 1
        self._bytes += size
        return True

    def note_rejection(self, key: str, code: ErrorCode, detail: str) -> None:
        """Record a sample refused on the receive path; the worker reports it."""
        self.notes.append((key, code, detail))
        self.wake()

    def wake(self) -> None:
        """Wake the worker."""
        with self.cond:
            self.cond.notify()

    def stop(self) -> None:
        """Refuse new samples from now on and wake the worker (invariant 3)."""
        with self.cond:
            self.stopping = True
            self.cond.notify()

    def depth(self) -> int:
        """Messages held (in the queue and in the worker's lanes)."""
        return self._held

    def give_back(self, items: Iterable[Inbound]) -> None:
        """Release the bounds held by handled items."""
        with self.cond:
            self.release(items)

    def release(self, items: Iterable[Inbound]) -> None:
        """``give_back`` for a caller that holds ``cond``."""
        for item in items:
            size = len(item.payload)
            self._held -= 1
            self._bytes -= size
            load = self._per_key.get(item.key)
            if load is not None:
                load[0] -= 1
                load[1] -= size
                if load[0] <= 0:
                    del self._per_key[item.key]


def cache_replies(
    items: Iterable[Inbound], limits: WireLimits
) -> list[tuple[tuple[str, str], str, list[Frame], bool]]:
    """Catch-up replies and ends, in queue order, as (robot, session, frames, query ended).

    At a query's end its robot's replies so far come with it; replies whose query has not
    ended yet follow, per robot and session (they fill the hold now, the end releases it).
    A reply is a frame the robot published before, checked (or refused) when it first
    arrived: one that does not decode is dropped without an error event, and an end (a
    plain put, never in a cache) is ignored.
    """
    out: list[tuple[tuple[str, str], str, list[Frame], bool]] = []
    frames: dict[tuple[str, str], list[Frame]] = {}
    for item in items:
        try:
            fleet, robot, _stream = parse_robot_key(item.key)
        except WireError:
            continue
        if item.kind == CATCHUP_DONE:
            key = (fleet, robot)
            out.append((key, item.payload.decode(), frames.pop(key, []), True))
            continue
        try:
            message = decode_inbound(item.payload, limits)
        except WireError:
            continue
        if isinstance(message, Frame):
            frames.setdefault((fleet, robot), []).append(message)
    for key, robot_frames in frames.items():
        for session_id in {f.session for f in robot_frames}:
            mine = [f for f in robot_frames if f.session == session_id]
            out.append((key, session_id, mine, False))
    return out

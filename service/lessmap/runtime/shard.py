"""A shard: one inbound queue, one worker thread, the sessions of the robots hashed to it.

The receive path never blocks Zenoh: the receiver's sweep (``receiver.py``) hands what the
frames channels held to ``offer_many``, which appends it to the shard's queue (bounded in
messages and in bytes, and per robot to a quarter of both, so one robot cannot fill it for
the others) under one lock and with one wake-up of the worker per sweep. A robot always
hashes to the same shard, so its frames are handled in order by one thread; shards share
nothing but the Zenoh session, the metrics and the work budgets (``budget.py``).

Fair scheduling: the worker moves what arrived into one lane per robot (still raw bytes,
still counted against the bounds) and serves the lanes by deficit round robin. Every round,
each robot with pending messages gets ``fair_quantum`` cost units (roughly pair updates; a
frame costs its k(k-1)/2 pairs plus a fixed overhead, a decision an estimate from its
CovGraph's edges, ``SessionTable.decision_cost``) and is served what its deficit affords:

- all of its pending frames with a decision after each, when that fits (a robot that keeps
  up on its own is never coalesced because another robot was expensive);
- else as many frames as fit with one decision per ``max_batch_frames`` (the robot's own
  load coalesces its own frames); the same when the shard is behind (a frame waited longer
  than ``coalesce_after_s``) for the robots asking more than a max-min fair share of one
  round's budget (``_coalescing_level``): deciding at every frame under a backlog would only
  deepen it (a decision costs 1.5-3 x a frame's counting), but a robot asking little is
  never coalesced because another one asks a lot;
- else nothing this round (the deficit carries over, so a frame larger than the quantum
  waits a few rounds while the other robots are served).

Turns of plain frames are planned robot by robot but handed to the table together, up to
``_FLUSH_FRAMES`` frames at a time (``SessionTable.handle_turns``: one call, one lock, one
outcome and one publish for a chunk of robots: at fleet rates most robots have one frame a
round, and a call, an outcome and a publish per frame cost a third of the core's own work).
Each robot keeps its own ``decide_every``; its frames stay in order (a robot has one turn a
round, and anything else of its turn, a catch-up reply or a probe, flushes the chunk first).
State queries are answered between chunks. ``max_batch_frames = 1`` still decides at every
frame. What a chunk produced is published before the lock is let go (``_step``): a
partition handed over in between would otherwise checkpoint a session whose transition the
fence then held back; ownership is checked again under that lock.

Catch-up: when the table holds frames beyond a gap it returns ``CatchupRequest``s; the worker
hands them to ``request_catchup`` (the service sends a Zenoh query with callbacks and
returns at once). The query's replies come back through ``offer`` as ``RECOVERED`` items and
its end as one ``CATCHUP_DONE`` item (admitted past the depth bound, so a full queue cannot
leave a hold waiting): the same FIFO, so the end is always taken after the replies.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

from lessmap.runtime.budget import pairs_of
from lessmap.runtime.sessions.model import FRAME_COST, Outcome, Rejection
from lessmap_schemas.codec import decode_inbound
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.keys import parse_robot_key
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.runtime.outbox import Outbox
    from lessmap.runtime.sessions.model import CatchupRequest
    from lessmap.runtime.sessions.table import SessionTable
    from lessmap_schemas.limits import WireLimits

log = logging.getLogger(__name__)

_BATCH_MAX = 4096  # messages moved from the queue to the lanes per round
_ROBOT_SHARE = 4  # one robot may hold at most 1/_ROBOT_SHARE of the queue (messages, bytes)
_LINGER_BELOW = 64  # a queue this deep already makes a batch: no lingering
_IDLE_SWEEP_S = 1.0
_FLUSH_FRAMES = 64  # plain frames of several robots' turns handed to the table at once
# What one cost unit takes on the worker (sessions.py: ~25 ns per pair update), to turn
# ``coalesce_after_s`` into a round's budget of cost units.
_SECONDS_PER_COST_UNIT = 25e-9
_KEYS_REMEMBERED = 65_536  # parsed robot keys kept (``_parse_key``)

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


@dataclass(slots=True)
class _Lane:
    """One robot's pending messages in the shard, and its deficit (cost units)."""

    items: deque[Inbound]
    deficit: float = 0.0
    # The head item decoded (kept when the robot could not afford it this round).
    head: Frame | SessionEnd | None = None


class Shard:
    """Owns a queue, per-robot lanes, a worker thread and a session table."""

    def __init__(
        self,
        index: int,
        table: SessionTable,
        outbox: Outbox,
        *,
        limits: WireLimits,
        queue_depth: int,
        queue_bytes: int,
        linger_s: float = 0.0,
        request_catchup: Callable[[Shard, CatchupRequest], None] | None = None,
        quantum: int = 5_000_000,
        coalesce_after_s: float = 0.05,
        owns: Callable[[str, str], bool] | None = None,
    ) -> None:
        self.index = index
        # False for a robot whose partition this instance handed over: its queued frames are
        # left to the new owner (which fetches them from the robot's cache).
        self._owns = owns
        self.table = table
        self.lock = threading.Lock()  # guards ``table`` between the worker and queries
        self._outbox = outbox
        self._limits = limits
        self._queue: deque[Inbound] = deque()
        self._queue_depth = queue_depth
        self._queue_bytes = queue_bytes
        # Messages and bytes taken and not yet handled (in the queue or in a lane), in all
        # and per key: ``offer`` bounds both, the worker gives them back after each turn.
        self._held = 0
        self._queued_bytes = 0
        self._per_key: dict[str, list[int]] = {}
        self._linger_s = linger_s
        self._request_catchup = request_catchup
        self._quantum = quantum
        self._coalesce_after_s = coalesce_after_s
        self._level = math.inf  # this round's ``_coalescing_level``
        self._lanes: dict[tuple[str, str], _Lane] = {}  # insertion order = round order
        self._robot_of: dict[str, tuple[str, str]] = {}  # valid keys seen: (fleet, robot)
        # Seconds waited by the round's frames, for the latency histograms (``_round``).
        self._queue_waits: list[float] = []
        self._frame_waits: list[float] = []
        # Planned turns of plain frames not yet handed to the table (``_flush``).
        self._deferred: list[tuple[tuple[str, str], list[Frame | SessionEnd], int | None]] = []
        self._deferred_items: list[Inbound] = []
        self._ready = threading.Condition()
        self._stopping = False
        self._abandon = False  # stop overran its time: leave the rest to the robots' caches
        self._thread = threading.Thread(
            target=self._run, name=f"lessmap-shard-{index}", daemon=True
        )
        self._last_sweep_s = time.monotonic()
        # Rejections decided on Zenoh's thread (queue full, payload too large), published by
        # the worker; deque appends are atomic, and maxlen bounds a flood.
        self._notes: deque[tuple[str, ErrorCode, str]] = deque(maxlen=10_000)

    # -- receive path (Zenoh's thread) -------------------------------------------------------

    def offer(self, item: Inbound) -> bool:
        """Enqueue a sample without blocking; False when the shard is full (caller reports).

        The end of a catch-up query is always taken (one per query under way, each a few
        bytes), so a hold never outlives its query because the queue was full. One robot
        (key) may hold at most a quarter of the messages and bytes.
        """
        with self._ready:
            taken = self._admit(item)
            if taken:
                self._ready.notify()
        return taken

    def offer_many(self, items: list[Inbound]) -> list[Inbound]:
        """Enqueue samples in order without blocking, as ``offer`` each; return those refused.

        One lock and one wake-up of the worker for the lot (the receive path's sweep).
        """
        with self._ready:
            admit = self._admit
            refused = [item for item in items if not admit(item)]
            if len(refused) < len(items):
                self._ready.notify()
        return refused

    def _admit(self, item: Inbound) -> bool:
        """Append one item if the bounds allow it (caller holds ``_ready``)."""
        size = len(item.payload)
        key = item.key
        load = self._per_key.get(key)
        if item.kind != CATCHUP_DONE and (
            self._stopping
            or self._held >= self._queue_depth
            or self._queued_bytes + size > self._queue_bytes
            or (
                load is not None
                and (
                    load[0] * _ROBOT_SHARE >= self._queue_depth
                    or (load[1] + size) * _ROBOT_SHARE > self._queue_bytes
                )
            )
        ):
            return False
        if load is None:
            self._per_key[key] = [1, size]
        else:
            load[0] += 1
            load[1] += size
        self._queue.append(item)
        self._held += 1
        self._queued_bytes += size
        return True

    def note_rejection(self, key: str, code: ErrorCode, detail: str) -> None:
        """Record a sample refused on the receive path; the worker reports it."""
        self._notes.append((key, code, detail))
        with self._ready:
            self._ready.notify()

    def depth(self) -> int:
        """Messages waiting (in the queue and in the robots' lanes)."""
        return self._held

    def lag_s(self, now: float) -> float:
        """Age of the oldest message waiting, seconds (0 when none waits)."""
        with self._ready:
            oldest = [self._queue[0].received_s] if self._queue else []
            # The lanes are the worker's; a racy read of their heads is good enough here.
            oldest += [
                lane.items[0].received_s for lane in list(self._lanes.values()) if lane.items
            ]
        live = [t for t in oldest if t > 0.0]
        return max(0.0, now - min(live)) if live else 0.0

    # -- worker ------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the worker thread."""
        self._thread.start()

    def stop(self, timeout_s: float) -> None:
        """Let the worker finish what is queued, then end it.

        A worker that has not drained within ``timeout_s`` is told to stop after its current
        turn, and waited for: the table is closed only once no worker touches it. What it
        leaves unapplied is still in the robots' publication caches, and the checkpoint
        written at the stop says exactly where each session stands, so a restart catches up.
        """
        with self._ready:
            self._stopping = True
            self._ready.notify()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            with self._ready:
                self._abandon = True
                left = self._held
            log.warning(
                "shard %d did not drain within %.1f s; %d message(s) left unapplied "
                "(a restart catches up from the robots' caches)",
                self.index,
                timeout_s,
                left,
            )
            self._thread.join()

    @property
    def stopping(self) -> bool:
        """True once ``stop`` was called: new samples are refused."""
        return self._stopping

    def _collect(self) -> None:
        """Move what arrived into the robots' lanes; wait for it when no lane has work."""
        with self._ready:
            while not self._queue and not self._lanes and not self._stopping and not self._notes:
                self._ready.wait(timeout=_IDLE_SWEEP_S / 2)
                if not self._queue:
                    break
            linger = not self._lanes and 0 < len(self._queue) < _LINGER_BELOW and not self._stopping
        if linger and self._linger_s > 0:
            # Woken by one frame: let the next few milliseconds of frames join this round.
            # A wake-up per frame costs as much CPU as the frame's own work at fleet rates.
            time.sleep(self._linger_s)
        unattributed: list[tuple[str, WireError]] = []
        robot_of = self._robot_of
        lanes = self._lanes
        with self._ready:
            queue = self._queue
            for _ in range(min(len(queue), _BATCH_MAX)):
                item = queue.popleft()
                robot_key = robot_of.get(item.key)
                if robot_key is None:
                    try:
                        robot_key = self._parse_key(item.key)
                    except WireError as exc:
                        self._give_back([item])
                        unattributed.append((item.key, exc))
                        continue
                lane = lanes.get(robot_key)
                if lane is None:
                    lane = lanes[robot_key] = _Lane(deque())
                lane.items.append(item)
        for key, error in unattributed:  # outside the lock: the callback never waits on a put
            self._outbox.reject_unattributed(key, error)

    def _parse_key(self, key: str) -> tuple[str, str]:
        """Return (fleet, robot) of a frames key, remembered: a robot's key arrives often."""
        fleet, robot, _stream = parse_robot_key(key)
        if len(self._robot_of) >= _KEYS_REMEMBERED:
            self._robot_of.clear()  # a churn of robots: start over rather than grow
        robot_key = self._robot_of[key] = (fleet, robot)
        return robot_key

    def holds_any(self, wanted: Callable[[str], bool]) -> bool:
        """True while a message of a robot key ``wanted`` names is queued or in a turn."""
        with self._ready:
            return any(wanted(key) for key in self._per_key)

    def _give_back(self, items: list[Inbound]) -> None:
        """Release the bounds held by handled items (caller may hold ``_ready``: RLock-free)."""
        for item in items:
            size = len(item.payload)
            self._held -= 1
            self._queued_bytes -= size
            load = self._per_key.get(item.key)
            if load is not None:
                load[0] -= 1
                load[1] -= size
                if load[0] <= 0:
                    del self._per_key[item.key]

    def _run(self) -> None:
        while True:
            self._collect()
            if self._notes:
                self._report_notes()
            if self._lanes:
                try:
                    self._round()
                except Exception:
                    # A bug must not kill the shard: log it, keep serving the other sessions.
                    log.exception("shard %d failed in a round", self.index)
            now = time.monotonic()
            if self.table.holds:
                self._step(now, self.table.release_overdue, now)
            if now - self._last_sweep_s >= _IDLE_SWEEP_S:
                self._last_sweep_s = now
                self._step(now, self.table.expire_idle, now)
            with self._ready:
                if self._abandon or (self._stopping and not self._queue and not self._lanes):
                    return

    def _report_notes(self) -> None:
        outcome = Outcome()
        while self._notes:
            key, code, detail = self._notes.popleft()
            try:
                fleet, robot, _stream = parse_robot_key(key)
            except WireError as exc:
                self._outbox.reject_unattributed(key, exc)
                continue
            outcome.rejections.append(Rejection(fleet, robot, None, code, detail, None))
        self._publish(outcome, time.monotonic())

    def _publish(self, outcome: Outcome, now: float) -> None:
        """Publish an outcome, then send the catch-up queries it asks for."""
        self._outbox.publish(outcome, now)
        self._ask_caches(outcome)

    def _step(self, now: float, step: Callable[..., Outcome], *args: Any) -> None:
        """Run one table method and publish its outcome under the table's lock (module doc)."""
        with self.lock:
            outcome = step(*args)
            self._outbox.publish(outcome, now)
        if outcome.evicted:
            # Sessions left memory: so do their parsed keys. Small objects kept alive past a
            # flood pin the allocator's arenas (measured: +23 MiB of 97 after 10,000 evictions).
            self._robot_of.clear()
        self._ask_caches(outcome)

    def _ask_caches(self, outcome: Outcome) -> None:
        if self._request_catchup is not None:
            for request in outcome.catchups:
                self._request_catchup(self, request)

    # -- deficit round robin -----------------------------------------------------------------

    def _round(self) -> None:
        """Give every robot with pending messages one turn (deficit round robin)."""
        metrics = self._outbox.metrics
        try:
            self._level = self._coalescing_level(time.monotonic())
            for key in list(self._lanes):
                if self._abandon:
                    return
                lane = self._lanes[key]
                lane.deficit += self._quantum
                self._turn(key, lane)
                if not lane.items:
                    del self._lanes[key]  # an empty lane keeps no credit (DRR)
                if len(self._deferred_items) >= _FLUSH_FRAMES:
                    self._flush()
        finally:
            # Planned turns are applied even when a turn failed: their bounds are held.
            self._flush()
            # The round's latencies, counted once (a histogram takes a lock per call).
            if self._queue_waits:
                metrics.queue_latency_seconds.observe_many(self._queue_waits)
                self._queue_waits = []
            if self._frame_waits:
                metrics.frame_latency_seconds.observe_many(self._frame_waits)
                self._frame_waits = []
            metrics.queue_depth.set(self._held)

    def _coalescing_level(self, now: float) -> float:
        """The per-frame demand above which a robot's turn shares its decisions this round.

        Infinite (the paper's loop for everyone) unless the shard is behind: the oldest
        pending frame waited longer than ``coalesce_after_s``. Then the round should take no
        more than that again, ``budget`` cost units, shared max-min fairly: the level L with
        sum(min(demand, L)) = budget, where a robot's demand is what deciding at each of its
        pending frames costs. A robot asking no more than L keeps a decision per frame.
        L is never below the largest indivisible demand of the round (a robot's pending
        frames with one decision): a robot whose single decision outweighs the budget
        (a huge CovGraph) then makes the others wait, but never changes their decisions.
        """
        lanes = self._lanes
        # Replies and probes carry no receipt time (0.0): only live frames say how late we are.
        live = [lane.items[0].received_s for lane in lanes.values() if lane.items]
        oldest = min((t for t in live if t > 0.0), default=None)
        if oldest is None or now - oldest <= self._coalesce_after_s:
            return math.inf
        with self.lock:
            cost = self.table.decision_cost
            pending = [(len(lane.items), cost(key)) for key, lane in lanes.items()]
        demands = sorted(n * (FRAME_COST + d) for n, d in pending)
        floor = max(n * FRAME_COST + d for n, d in pending)
        remaining = self._coalesce_after_s / _SECONDS_PER_COST_UNIT
        for index, demand in enumerate(demands):
            share = remaining / (len(demands) - index)
            if demand > share:
                return max(share, floor)
            remaining -= demand
        return math.inf

    def _decoded_head(self, key: tuple[str, str], lane: _Lane, out: list[Rejection]) -> bool:
        """Decode the lane's head (a live sample) into ``lane.head``; drop it if it is bad.

        Returns False when the head was dropped (a decoding failure, reported in ``out``).
        """
        if lane.head is not None or lane.items[0].kind != LIVE:
            return True
        item = lane.items[0]
        try:
            lane.head = decode_inbound(item.payload, self._limits)
        except WireError as exc:
            out.append(Rejection(key[0], key[1], None, exc.code, str(exc), None))
            lane.items.popleft()
            with self._ready:
                self._give_back([item])
            return False
        return True

    def _turn(self, key: tuple[str, str], lane: _Lane) -> None:
        """Serve one robot what its deficit affords, deciding per frame when that fits."""
        if self._owns is not None and not self._owns(*key):
            dropped = list(lane.items)
            lane.items.clear()
            lane.head = None
            with self._ready:
                self._give_back(dropped)
            self._outbox.metrics.frames_foreign.inc(len(dropped))
            return
        now = time.monotonic()
        rejected: list[Rejection] = []
        with self.lock:
            decision = self.table.decision_cost(key)
        # Plan: (item, decoded message or None, its cost without a decision).
        plan: list[tuple[Inbound, Frame | SessionEnd | None, int]] = []
        total = 0  # cost of the planned messages, decisions left out
        # The plan affords a decision after every message, unless the shard is behind and
        # this robot asks more than its fair share of the round (``_coalescing_level``).
        fits_per_frame = len(lane.items) * (FRAME_COST + decision) <= self._level
        while lane.items and len(plan) < len(lane.items):
            index = len(plan)
            if index == 0 and not self._decoded_head(key, lane, rejected):
                continue
            item = lane.items[index]
            message: Frame | SessionEnd | None = None
            if item.kind == LIVE:
                if index == 0:
                    message = lane.head
                else:
                    try:
                        message = decode_inbound(item.payload, self._limits)
                    except WireError:
                        break  # reported when it reaches the head of the lane
            cost = FRAME_COST
            if isinstance(message, Frame):
                cost += pairs_of(len(message.features))
            if fits_per_frame and total + cost + (index + 1) * decision > lane.deficit:
                fits_per_frame = False
            if not fits_per_frame and total + cost + decision > lane.deficit:
                break  # the rest waits for the next round (or more credit)
            total += cost
            plan.append((item, message, cost))
        if rejected:
            self._publish(Outcome(rejections=rejected), now)
        if not plan:
            return
        spent = total + (len(plan) if fits_per_frame else 1) * decision
        lane.deficit = max(0.0, lane.deficit - spent) if len(plan) < len(lane.items) else 0.0
        for _ in plan:
            lane.items.popleft()
        lane.head = None
        self._serve(key, plan, now, 1 if fits_per_frame else None)

    def _serve(
        self,
        key: tuple[str, str],
        plan: list[tuple[Inbound, Frame | SessionEnd | None, int]],
        now: float,
        decide_every: int | None,
    ) -> None:
        """Hand one robot's planned messages to the table in arrival order."""
        fleet, robot = key
        queue_waits = self._queue_waits
        debug = log.isEnabledFor(logging.DEBUG)
        if all(item.kind == LIVE and message is not None for item, message, _ in plan):
            # The common case: plain frames, handed to the table with other robots' turns.
            messages: list[Frame | SessionEnd] = []
            for item, message, _cost in plan:
                queue_waits.append(now - item.received_s)
                messages.append(message)  # type: ignore[arg-type]  # checked just above
                if debug:
                    log.debug(
                        "<<- %s %s seq=%s",
                        item.key,
                        type(message).__name__,
                        getattr(message, "seq", None),
                    )
            self._deferred.append((key, messages, decide_every))
            self._deferred_items += [item for item, _message, _cost in plan]
            return
        self._flush()  # anything else of this robot comes after its earlier turns
        live: list[tuple[str, str, Frame | SessionEnd]] = []
        # The session when ``live`` holds only probed frames of it (judged news together).
        probed_of: str | None = None
        recovered: list[Inbound] = []
        items = [item for item, _message, _cost in plan]
        try:
            for item, message, _cost in plan:
                if item.kind == PROBE:
                    probe = self._decoded_probe(item)
                    if probe is None:
                        continue
                    # A probe is judged on what the messages before it did to the table,
                    # so they are applied first: a live end closes the session that a copy
                    # of its last frame would otherwise reach as a straggler (counted as a
                    # rejected SESSION_CLOSED), a live frame makes the copy a redelivery,
                    # and the end of a session whose frames are among them is news only
                    # once they applied. Probed frames of one session (those held at a
                    # take-over) are judged together: one only raises the last seq the
                    # next is judged against, and a copy judged news is marked, so its
                    # second offer is dropped uncounted.
                    if recovered:
                        self._recover(recovered, now)
                        recovered = []
                    if live and not (isinstance(probe, Frame) and probe.session == probed_of):
                        self._apply(live, now, decide_every)
                        live = []
                    news = self._news(fleet, robot, probe)
                    if news is not None:
                        probed_of = news.session if isinstance(news, Frame) else None
                        live.append((fleet, robot, news))
                    continue
                probed_of = None
                if item.kind != LIVE:
                    if live:
                        self._apply(live, now, decide_every)
                        live = []
                    recovered.append(item)
                    continue
                if recovered:
                    self._recover(recovered, now)
                    recovered = []
                queue_waits.append(now - item.received_s)
                if message is None:
                    try:
                        message = decode_inbound(item.payload, self._limits)
                    except WireError as exc:
                        rejection = Rejection(fleet, robot, None, exc.code, str(exc), None)
                        self._publish(Outcome(rejections=[rejection]), now)
                        continue
                if debug:
                    log.debug(
                        "<<- %s %s seq=%s",
                        item.key,
                        type(message).__name__,
                        getattr(message, "seq", None),
                    )
                live.append((fleet, robot, message))
            if live:
                self._apply(live, now, decide_every)
            if recovered:
                self._recover(recovered, now)
        finally:
            with self._ready:
                self._give_back(items)
        done = time.monotonic()
        self._frame_waits += [done - item.received_s for item in items if item.kind == LIVE]

    def _flush(self) -> None:
        """Hand the deferred turns to the table in one step, then release their bounds."""
        turns, items = self._deferred, self._deferred_items
        if not turns:
            return
        self._deferred, self._deferred_items = [], []
        now = time.monotonic()
        try:
            self._step(now, self._handle_owned_turns, turns, now)
        finally:
            with self._ready:
                self._give_back(items)
        done = time.monotonic()
        self._frame_waits += [done - item.received_s for item in items]

    def _handle_owned_turns(
        self,
        turns: list[tuple[tuple[str, str], list[Frame | SessionEnd], int | None]],
        now: float,
    ) -> Outcome:
        """``handle_turns`` for the robots still owned (called under the lock, ``_step``)."""
        owns = self._owns
        if owns is not None:
            kept = [turn for turn in turns if owns(*turn[0])]
            if len(kept) < len(turns):
                foreign = sum(len(turn[1]) for turn in turns) - sum(len(t[1]) for t in kept)
                self._outbox.metrics.frames_foreign.inc(foreign)
                turns = kept
        return self.table.handle_turns(turns, now)

    def _decoded_probe(self, item: Inbound) -> Frame | SessionEnd | None:
        """A probed message decoded, or None (refused when it first arrived, if it did)."""
        try:
            return decode_inbound(item.payload, self._limits)
        except WireError:
            return None

    def _news(
        self, fleet: str, robot: str, message: Frame | SessionEnd
    ) -> Frame | SessionEnd | None:
        """A probed message, if the table does not know it yet."""
        with self.lock:
            if not self.table.is_news(fleet, robot, message):
                return None
            if isinstance(message, Frame):
                self.table.note_from_cache((fleet, robot), message.session, message.seq)
            return message

    def _apply(
        self, live: list[tuple[str, str, Frame | SessionEnd]], now: float, decide_every: int | None
    ) -> None:
        self._step(now, self.table.handle_batch, live, now, decide_every)

    def _recover(self, items: list[Inbound], now: float) -> None:
        """Hand catch-up replies and ends to the table, in queue order.

        A reply is a frame the robot published before, already checked (or refused) when it
        first arrived if it did: one that does not decode is dropped without an error event.
        """
        frames: dict[tuple[str, str], list[Frame]] = {}
        for item in items:
            try:
                fleet, robot, _stream = parse_robot_key(item.key)
            except WireError:
                continue
            if item.kind == CATCHUP_DONE:
                key, session_id = (fleet, robot), item.payload.decode()
                got = frames.pop(key, [])
                self._step(now, self.table.recover, key, session_id, got, now)
                self._step(now, self.table.catchup_done, key, session_id, now)
                continue
            try:
                message = decode_inbound(item.payload, self._limits)
            except WireError:
                continue
            if isinstance(message, SessionEnd):
                continue  # ends are plain puts, never in a cache; a forged one changes nothing
            frames.setdefault((fleet, robot), []).append(message)
        for (fleet, robot), robot_frames in frames.items():
            # Replies whose query has not ended yet: fill the hold now, release at the end.
            sessions = {f.session for f in robot_frames}
            for session_id in sessions:
                mine = [f for f in robot_frames if f.session == session_id]
                self._step(now, self.table.recover, (fleet, robot), session_id, mine, now)

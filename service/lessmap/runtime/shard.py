"""A shard: one inbound queue, one worker thread, and the sessions of the robots hashed to it.

Invariants (the why: ``docs/decisions/0003-shard-actor.md``, ``0004-fair-scheduling.md``):

1. A robot always hashes to the same shard, so its frames are handled in order by one thread.
2. Only the worker touches the session table (an actor): queries, hand-overs and the stop
   are commands on its inbox (``read``, ``drain``, ``hand_over_sessions``, ``stop``), answered
   through ``concurrent.futures.Future``s and run between chunks, never inside one.
3. What a chunk produced is published before the worker takes a command, so a hand-over
   never checkpoints a session whose transition the fence then held back.
4. The lanes are served by deficit round robin: a robot that keeps up is decided every
   frame; one over its share is coalesced by its own load, never because of another's.
5. Catch-up queries go out through ``request_catchup`` (callbacks that only enqueue); their
   replies and end come back through the same FIFO, so the end follows its replies.
6. A robot whose decisions take long is moved to the shard's heavy lane (``heavy.py``): a
   second shard, fed by this worker, so no robot here waits for such a decision.
"""

from __future__ import annotations

import logging
import math
import operator
import threading
import time
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any, TypeVar

from lessmap.runtime.arrivals import Arrivals
from lessmap.runtime.commands import CommandInbox
from lessmap.runtime.fairness import Lane, Planned, ShardPolicy, coalescing_level, plan_turn
from lessmap.runtime.heavy import and_heavy
from lessmap.runtime.inbound import (
    CATCHUP_DONE,
    LIVE,
    PROBE,
    RECOVERED,
    Inbound,
    InboundQueue,
    cache_replies,
)
from lessmap.runtime.sessions.model import Outcome, Rejection
from lessmap_schemas.codec import decode_inbound
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.keys import parse_robot_key
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.runtime.heavy import HeavyLane
    from lessmap.runtime.outbox import Outbox
    from lessmap.runtime.sessions.model import CatchupRequest, MovedRobot
    from lessmap.runtime.sessions.table import SessionTable
    from lessmap_schemas.limits import WireLimits

log = logging.getLogger(__name__)

_LINGER_BELOW = 64  # a queue this deep already makes a batch: no lingering
_IDLE_SWEEP_S = 1.0
_FLUSH_FRAMES = 64  # plain frames of several robots' turns handed to the table at once

T = TypeVar("T")
Turn = tuple[tuple[str, str], list[Frame | SessionEnd], int | None]

__all__ = ["CATCHUP_DONE", "LIVE", "PROBE", "RECOVERED", "Inbound", "Shard", "ShardPolicy"]


class Shard:
    """Owns a queue, per-robot lanes, a worker thread and a session table."""

    def __init__(
        self,
        index: int,
        table: SessionTable,
        outbox: Outbox,
        *,
        limits: WireLimits,
        policy: ShardPolicy,
        request_catchup: Callable[[Shard, CatchupRequest], None] | None = None,
        owns: Callable[[str, str], bool] | None = None,
        heavy: HeavyLane[Shard] | None = None,
    ) -> None:
        self.index = index
        self._heavy = heavy  # invariant 6
        # False for a robot whose partition this instance handed over: its queued frames are
        # left to the new owner (which fetches them from the robot's cache).
        self._owns = owns
        self._table = table  # the worker's alone (invariant 2)
        self._outbox = outbox
        self._limits = limits
        self._inbound = InboundQueue(policy.queue_depth, policy.queue_bytes)
        self._ready = self._inbound.cond
        self._linger_s = policy.linger_s
        self._request_catchup = request_catchup
        self._quantum = policy.quantum
        self._coalesce_after_s = policy.coalesce_after_s
        self._level = math.inf  # this round's ``coalescing_level``
        self._lanes: dict[tuple[str, str], Lane] = {}  # insertion order = round order
        self._arrivals = Arrivals(self._inbound, self._lanes, heavy, outbox.reject_unattributed)
        # Seconds waited by the round's frames, for the latency histograms (``_round``).
        self._queue_waits: list[float] = []
        self._frame_waits: list[float] = []
        # Planned turns of plain frames not yet handed to the table (``_flush``).
        self._deferred: list[Turn] = []
        self._deferred_items: list[Inbound] = []
        self._commands = CommandInbox(self._ready)  # invariant 2
        self._abandon = False  # stop overran its time: leave the rest to the robots' caches
        self._close_cause = "shutdown"  # why the sessions close when the worker ends
        self._sessions_closed = False
        self._thread = threading.Thread(
            target=self._run,
            name=f"lessmap-shard-{index}" if policy.heavy_of is None else f"lessmap-heavy-{index}",
            daemon=True,
        )
        self._last_sweep_s = time.monotonic()
        self._store_heals = 0  # the table's ``store_heals`` when this shard last checkpointed
        self.open_sessions = 0  # sessions in memory, as the worker last saw them (health)

    # -- receive path ----------------------------------------------------------------------

    def offer(self, item: Inbound) -> bool:
        """Enqueue a sample without blocking; False when the shard is full (caller reports)."""
        return self._inbound.offer(item)

    def offer_many(self, items: list[Inbound]) -> list[Inbound]:
        """Enqueue samples in order without blocking; return those refused (one wake-up)."""
        return self._inbound.offer_many(items)

    def note_rejection(self, key: str, code: ErrorCode, detail: str) -> None:
        """Record a sample refused on the receive path; the worker reports it."""
        self._inbound.note_rejection(key, code, detail)

    def depth(self) -> int:
        """Messages waiting (in the queue and in the robots' lanes)."""
        return self._inbound.depth()

    def lag_s(self, now: float) -> float:
        """Age of the oldest message waiting, seconds (0 when none waits)."""
        queue = self._inbound.queue
        with self._ready:
            oldest = [queue[0].received_s] if queue else []
            # The lanes are the worker's; a racy read of their heads is good enough here.
            oldest += [
                lane.items[0].received_s for lane in list(self._lanes.values()) if lane.items
            ]
        live = [t for t in oldest if t > 0.0]
        return max(0.0, now - min(live)) if live else 0.0

    @property
    def lanes(self) -> tuple[Shard, ...]:
        """This shard and its heavy lane, if it has one (each has a table)."""
        return (self,) if self._heavy is None else (self, self._heavy.worker)

    @property
    def stopping(self) -> bool:
        """True once ``stop`` was called: new samples are refused."""
        return self._inbound.stopping

    # -- commands (invariant 2) --------------------------------------------------------------

    def read(self, reader: Callable[[SessionTable], T]) -> Future[T]:
        """Run ``reader`` on the table in the worker, between chunks; its answer comes back."""
        return self._commands.send(lambda: reader(self._table))

    def drain(self, wanted: Callable[[str, str], bool]) -> Future[None]:
        """Apply now what is queued for the robots ``wanted`` names (before a hand-over)."""
        done = self._commands.send(lambda: self._serve_now(wanted))
        return and_heavy(done, self._heavy, lambda heavy: heavy.drain(wanted), lambda _a, b: b)

    def adopt(self, moved: MovedRobot) -> Future[None]:
        """Take a robot another shard's worker released (its heavy lane's move)."""

        def command() -> None:
            self._table.adopt_robot(moved)
            self.open_sessions = len(self._table)

        return self._commands.send(command)

    def hand_over_sessions(self, leaving: Callable[[str, str], bool], now_s: float) -> Future[int]:
        """Checkpoint and drop the sessions of robots ``leaving`` names; how many."""

        def command() -> int:
            outcome = self._table.hand_over(leaving, now_s)
            # Counters and checkpoints only (the fence is closed): not those of a session
            # with a fenced transition (the next owner decides it anew).
            self._outbox.publish(outcome, now_s)
            self.open_sessions = len(self._table)
            return outcome.evicted

        done = self._commands.send(command)
        return and_heavy(
            done, self._heavy, lambda heavy: heavy.hand_over_sessions(leaving, now_s), operator.add
        )

    def _serve_now(self, wanted: Callable[[str, str], bool]) -> None:
        """Serve in full, whatever their deficit, the lanes of the robots ``wanted`` names."""
        self._arrivals.move_queued()  # what arrived before this command, not what follows it
        for key in [k for k in self._lanes if wanted(*k)]:
            lane = self._lanes[key]
            while lane.items:
                lane.deficit = math.inf
                self._turn(key, lane)
            self._flush()
            del self._lanes[key]

    # -- worker ------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the worker thread (and the heavy lane's)."""
        if self._heavy is not None:
            self._heavy.worker.start()
        self._thread.start()

    def stop(self, timeout_s: float, cause: str = "shutdown") -> None:
        """Let the worker finish what is queued, close the sessions (``cause``), end it.

        A worker that has not drained within ``timeout_s`` is told to stop after its current
        turn, and waited for. What it leaves unapplied is still in the robots' publication
        caches, and the checkpoint written at the stop says exactly where each session
        stands, so a restart catches up.
        """
        self._close_cause = cause
        started_s = time.monotonic()
        self._inbound.stop()
        if self._thread.ident is None:  # never started: the table is the caller's
            self._commands.finish()
        else:
            self._thread.join(timeout_s)
        if self._thread.is_alive():
            with self._ready:
                self._abandon = True
                left = self._inbound.depth()
            log.warning(
                "shard %d did not drain within %.1f s; %d message(s) left unapplied "
                "(a restart catches up from the robots' caches)",
                self.index,
                timeout_s,
                left,
            )
            self._thread.join()
        # A worker that died of a bug (or never started) left them: closed on this thread.
        self._commands.send(self._close_sessions).result()
        if self._heavy is not None:  # after this worker forwarded all it held
            left_s = timeout_s - (time.monotonic() - started_s)
            self._heavy.worker.stop(max(0.1, left_s), cause)

    def _collect(self) -> None:
        """Move what arrived into the robots' lanes; wait for it when no lane has work."""
        inbound = self._inbound
        queue = inbound.queue
        with self._ready:
            while (
                not queue
                and not self._lanes
                and not inbound.stopping
                and not inbound.notes
                and not self._commands
            ):
                self._ready.wait(timeout=_IDLE_SWEEP_S / 2)
                if not queue:
                    break
            linger = not self._lanes and 0 < len(queue) < _LINGER_BELOW and not inbound.stopping
        if linger and self._linger_s > 0:
            # Woken by one frame: let the next few milliseconds of frames join this round.
            # A wake-up per frame costs as much CPU as the frame's own work at fleet rates.
            time.sleep(self._linger_s)
        self._arrivals.move()

    def _run(self) -> None:
        try:
            self._work()
        finally:
            # Invariant 2 still: the sessions are closed here, by their owner.
            if self._inbound.stopping:
                self._close_sessions()
            self._commands.finish()

    def _work(self) -> None:
        inbound = self._inbound
        while True:
            self._collect()
            self._commands.run_pending()
            if inbound.notes:
                self._report_notes()
            if self._lanes:
                try:
                    self._round()
                except Exception:
                    # A bug must not kill the shard: log it, keep serving the other sessions.
                    log.exception("shard %d failed in a round", self.index)
            now = time.monotonic()
            self._follow_store(now)
            if self._table.holds:
                self._step(now, self._table.release_overdue, now)
            if now - self._last_sweep_s >= _IDLE_SWEEP_S:
                self._last_sweep_s = now
                self._step(now, self._table.expire_idle, now)
            with self._ready:
                if self._abandon or (inbound.stopping and not inbound.queue and not self._lanes):
                    return

    def _follow_store(self, now: float) -> None:
        """Checkpoint every session again once the store healed; shard 0 reports the changes."""
        heals = self._table.store_heals
        if heals != self._store_heals:
            self._store_heals = heals
            self._step(now, self._table.checkpoint_open, now)
        if self.index == 0:
            self._outbox.report_store_changes()

    def _close_sessions(self) -> None:
        """Checkpoint (with a store) or close every session at the stop, and publish that."""
        if self._sessions_closed:
            return
        self._sessions_closed = True
        outcome = self._table.close_all(self._close_cause)
        self._outbox.publish(outcome, time.monotonic())
        self.open_sessions = len(self._table)

    def _report_notes(self) -> None:
        outcome = Outcome()
        notes = self._inbound.notes
        while notes:
            key, code, detail = notes.popleft()
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
        """Run one table method and publish its outcome (invariant 3)."""
        outcome = step(*args)
        self._outbox.publish(outcome, now)
        self.open_sessions = len(self._table)
        if outcome.evicted:
            # Sessions left memory: so do their parsed keys, which would otherwise pin the
            # allocator's arenas past a flood (docs/tuning/memory.md).
            self._arrivals.forget_keys()
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
            self._level = coalescing_level(
                self._lanes, self._table.decision_cost, time.monotonic(), self._coalesce_after_s
            )
            for key in list(self._lanes):
                if self._abandon:
                    return
                lane = self._lanes.get(key)
                if lane is None:
                    continue  # served by a command (``drain``)
                lane.deficit += self._quantum
                self._turn(key, lane)
                if not lane.items:
                    del self._lanes[key]  # an empty lane keeps no credit (DRR)
                if len(self._deferred_items) >= _FLUSH_FRAMES:
                    self._flush()
                    self._commands.run_pending()  # between chunks (invariant 2)
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
            metrics.queue_depth.set(self._inbound.depth())

    def _decoded_head(self, key: tuple[str, str], lane: Lane, out: list[Rejection]) -> bool:
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
            self._inbound.give_back([item])
            return False
        return True

    def _turn(self, key: tuple[str, str], lane: Lane) -> None:
        """Serve one robot what its deficit affords, deciding per frame when that fits."""
        if self._owns is not None and not self._owns(*key):
            dropped = list(lane.items)
            lane.items.clear()
            lane.head = None
            self._inbound.give_back(dropped)
            self._outbox.metrics.frames_foreign.inc(len(dropped))
            return
        now = time.monotonic()
        rejected: list[Rejection] = []
        decision = self._table.decision_cost(key)
        pending = len(lane.items)
        while lane.items and not self._decoded_head(key, lane, rejected):
            pass  # a head that does not decode is dropped (and reported)
        if self._heavy is not None and self._moved_to_heavy(key, lane):
            if rejected:
                self._publish(Outcome(rejections=rejected), now)
            return
        plan: list[Planned] = []
        fits_per_frame = True
        if lane.items:
            plan, fits_per_frame, spent = plan_turn(
                lane, decision, self._level, pending, self._decoded_or_none
            )
        if rejected:
            self._publish(Outcome(rejections=rejected), now)
        if not plan:
            return
        lane.deficit = max(0.0, lane.deficit - spent) if len(plan) < len(lane.items) else 0.0
        for _ in plan:
            lane.items.popleft()
        lane.head = None
        self._serve(key, plan, now, 1 if fits_per_frame else None)

    def _moved_to_heavy(self, key: tuple[str, str], lane: Lane) -> bool:
        """Move a robot whose next decision is too costly to the heavy lane (invariant 6)."""
        heavy = self._heavy
        head = lane.head
        if not isinstance(head, Frame) or heavy is None:
            return False
        if not heavy.is_heavy(self._table.decision_cost(key, len(head.features))):
            return False
        self._flush()  # the robot's planned frames are applied here first
        moved = self._table.release_robot(key)
        if moved is None:
            return False  # a catch-up holds its frames: it moves at a later turn
        self.open_sessions = len(self._table)
        items = list(lane.items)
        lane.items.clear()
        lane.head = None
        self._inbound.give_back(items)
        heavy.move(key, moved, items)
        return True

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
                    _log_received(item, message)
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
                    probe = self._decoded_or_none(item)
                    if probe is None:
                        continue
                    # Judged on what the messages before it did to the table, so those
                    # are applied first; probed frames of one session are judged together
                    # (docs/decisions/0004-fair-scheduling.md, "Probes in a turn").
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
                    _log_received(item, message)
                live.append((fleet, robot, message))
            if live:
                self._apply(live, now, decide_every)
            if recovered:
                self._recover(recovered, now)
        finally:
            self._inbound.give_back(items)
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
            self._inbound.give_back(items)
        done = time.monotonic()
        self._frame_waits += [done - item.received_s for item in items]

    def _handle_owned_turns(
        self,
        turns: list[Turn],
        now: float,
    ) -> Outcome:
        """``handle_turns`` for the robots still owned (ownership checked again here)."""
        owns = self._owns
        if owns is not None:
            kept = [turn for turn in turns if owns(*turn[0])]
            if len(kept) < len(turns):
                foreign = sum(len(turn[1]) for turn in turns) - sum(len(t[1]) for t in kept)
                self._outbox.metrics.frames_foreign.inc(foreign)
                turns = kept
        return self._table.handle_turns(turns, now)

    def _decoded_or_none(self, item: Inbound) -> Frame | SessionEnd | None:
        """A probed message decoded, or None (refused when it first arrived, if it did)."""
        try:
            return decode_inbound(item.payload, self._limits)
        except WireError:
            return None

    def _news(
        self, fleet: str, robot: str, message: Frame | SessionEnd
    ) -> Frame | SessionEnd | None:
        """A probed message, if the table does not know it yet."""
        if not self._table.is_news(fleet, robot, message):
            return None
        if isinstance(message, Frame):
            self._table.note_from_cache((fleet, robot), message.session, message.seq)
        return message

    def _apply(
        self, live: list[tuple[str, str, Frame | SessionEnd]], now: float, decide_every: int | None
    ) -> None:
        self._step(now, self._table.handle_batch, live, now, decide_every)

    def _recover(self, items: list[Inbound], now: float) -> None:
        """Hand catch-up replies and ends to the table, in queue order."""
        table = self._table
        for key, session_id, frames, done in cache_replies(items, self._limits):
            self._step(now, table.recover, key, session_id, frames, now)
            if done:
                self._step(now, table.catchup_done, key, session_id, now)


def _log_received(item: Inbound, message: Frame | SessionEnd | None) -> None:
    log.debug("<<- %s %s seq=%s", item.key, type(message).__name__, getattr(message, "seq", None))

"""The robot sessions of one shard: the orchestrator of the rules. No Zenoh, no threads.

Rules (the service's ordering contract, schemas/README.md; details in the modules named):

1. One open session per (fleet, robot). A frame with a new session id closes the open one
   and starts a new CovGraph; a closed id is never reopened (SESSION_CLOSED), but a cache's
   copy of a frame it received is dropped uncounted.
2. Frames of a session are applied in seq order exactly once, a batch sorted by seq first;
   repeats, gaps and late frames are counted exactly once each (``seq.py``, ``apply.py``).
3. Coalescing: up to ``max_batch_frames`` frames, then one decision (1: every frame).
4. Limits and budgets are checked before the core (``limits.py``); a full shard evicts
   idle sessions before it refuses a new one (``durability.py``).
5. Checkpoints travel in the outcome, sessions resume from the store (``durability.py``),
   frames beyond a gap wait for the robot's cache (``catchup.py``).
6. A bug in one session resets that session only (INTERNAL); the others go on.
7. A robot moves to another table whole (``release_robot``, ``adopt_robot``): its open
   session, closed ids and final state, never while a catch-up holds its frames.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import TYPE_CHECKING

from lessmap.runtime.sessions.apply import Applier, report_gap
from lessmap.runtime.sessions.catchup import Holds, tail_awaited
from lessmap.runtime.sessions.durability import EVICT_MIN_IDLE_S, Durability, evictable
from lessmap.runtime.sessions.limits import Budgets, kept_pairs
from lessmap.runtime.sessions.model import (
    DECISION_COST_PER_EDGE,
    FRAME_COST,
    MovedRobot,
    Outcome,
    RobotSession,
)
from lessmap.runtime.sessions.policy import CatchupPolicy, Clocks, DurabilityPolicy, SharedBudgets
from lessmap.runtime.sessions.seq import CacheMarks, ClosedIds, RobotKey
from lessmap.runtime.sessions.wire import session_area_graph, session_state
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from lessmap.runtime.sessions.policy import Identity, Segmenting, SessionLimits
    from lessmap.runtime.store import CheckpointStore
    from lessmap_schemas.messages import AreaGraph, SessionState, SubmapSummary

Turn = tuple[RobotKey, list[Frame | SessionEnd], int | None]


class SessionTable:
    """The open sessions of one shard and the rules above."""

    def __init__(
        self,
        segmenting: Segmenting,
        limits: SessionLimits,
        *,
        identity: Identity,
        durability: DurabilityPolicy | None = None,
        catchup: CatchupPolicy | None = None,
        budgets: SharedBudgets | None = None,
        store: CheckpointStore | None = None,
        clocks: Clocks | None = None,
    ) -> None:
        clocks = clocks or Clocks()
        self._segmenting = segmenting
        self._limits = limits
        self._identity = identity
        self._budgets = Budgets(limits, budgets or SharedBudgets())
        self._durability = Durability(
            store, durability or DurabilityPolicy(), identity, clocks.records
        )
        self._holds = Holds(catchup or CatchupPolicy())
        self._marks = CacheMarks()
        self._apply = Applier(
            self._budgets,
            self._marks,
            clocks.decisions,
            limits.max_batch_frames,
            lambda session: segmenting.new_segmenter(session.fleet),
        )
        self._closed = ClosedIds(4 * limits.max_sessions)
        # Least recently active first: a full shard evicts from the front.
        self._open: OrderedDict[RobotKey, RobotSession] = OrderedDict()
        # Closed sessions leave only their final state (the CovGraph is freed), kept for
        # state and submap queries until max_sessions newer ones push it out.
        self._final_states: OrderedDict[RobotKey, SessionState] = OrderedDict()
        self._final_graphs: dict[RobotKey, AreaGraph] = {}  # the same robots' area graphs

    def __len__(self) -> int:
        return len(self._open)

    @property
    def _store(self) -> CheckpointStore | None:
        return self._durability.store

    # -- reads -------------------------------------------------------------------------------

    def robots(self) -> list[RobotKey]:
        """Every robot with an open or remembered closed session."""
        return list(dict.fromkeys([*self._open, *self._final_states]))

    def knows(self, fleet: str, robot: str) -> bool:
        """Whether the robot is one of ``robots()`` (an open or remembered closed session)."""
        key = (fleet, robot)
        return key in self._open or key in self._final_states

    def is_news(self, fleet: str, robot: str, message: Frame | SessionEnd) -> bool:
        """True when a message found in a robot's cache is not known here yet.

        For the probe of a partition just taken over and the frames held while it was
        handed over: news is a frame of an unknown session or above the last seq seen (in
        memory, else in the store), or the end of a session open here (applied, it would
        have closed it); anything else is dropped uncounted (it was counted on arrival).
        """
        key = (fleet, robot)
        if (key, message.session) in self._closed:
            return False
        session = self._open.get(key)
        if session is None:
            return self._durability.stored_news(key, message)
        if session.session != message.session:
            return isinstance(message, Frame)
        return isinstance(message, SessionEnd) or not session.is_repeat(message.seq)

    def note_from_cache(self, key: RobotKey, session_id: str, seq: int) -> None:
        """Remember that frame ``seq`` of a session came (or comes) from the robot's cache."""
        self._marks.note(key, session_id, seq)

    def state(self, fleet: str, robot: str) -> SessionState | None:
        """Return the state of a robot's open session, else of its last closed one."""
        key = (fleet, robot)
        session = self._open.get(key)
        if session is not None:
            epoch = self._identity.epoch_of(fleet, robot)
            return session_state(session, self._identity.instance, is_open=True, epoch=epoch)
        final = self._final_states.get(key)
        if final is not None or self._store is None:
            return final
        return self._durability.stored_state(key)

    def area_graph(self, fleet: str, robot: str) -> AreaGraph | None:
        """Return the area graph of a robot's open session, else of its last closed one."""
        key = (fleet, robot)
        session = self._open.get(key)
        if session is not None:
            return self._area_graph_of(session)
        final = self._final_graphs.get(key)
        if final is not None or self._store is None:
            return final
        return self._durability.stored_area_graph(key)

    def submap(
        self, fleet: str, robot: str, submap_id: int
    ) -> tuple[SessionState, SubmapSummary, bool] | None:
        """Return (session state, submap, is the submap open) for a submap id, if known."""
        state = self.state(fleet, robot)
        if state is None:
            return None
        if state.current_submap.id == submap_id:
            return state, state.current_submap, state.open
        for closed in state.closed_submaps:
            if closed.id == submap_id:
                return state, closed, False
        return None

    def decision_cost(self, key: RobotKey, features: int = 0) -> int:
        """Estimated cost in scheduler units of a robot's decision after a frame of ``features``."""
        session = self._open.get(key)
        keeps = self._segmenting if session is None else session.segmenter  # its sampling
        edges = (0 if session is None else session.edges) + kept_pairs(keeps, features)
        return FRAME_COST + DECISION_COST_PER_EDGE * edges

    @property
    def edges(self) -> int:
        """Edges held by this table's sessions (an upper bound)."""
        return sum(s.edges for s in self._open.values())

    @property
    def holds(self) -> int:
        """Sessions waiting for a catch-up."""
        return len(self._holds)

    # -- frames ------------------------------------------------------------------------------

    def handle_batch(
        self,
        messages: Iterable[tuple[str, str, Frame | SessionEnd]],
        now_s: float,
        decide_every: int | None = None,
    ) -> Outcome:
        """Apply a batch of decoded messages (arrival order) and decide once per session.

        ``decide_every`` lowers the coalescing of this call (the fair scheduler asks for 1
        when a robot's frames fit its share); it never raises it above ``max_batch_frames``.
        """
        per_robot: dict[RobotKey, list[Frame | SessionEnd]] = {}
        for fleet, robot, message in messages:
            per_robot.setdefault((fleet, robot), []).append(message)
        return self.handle_turns(
            [(key, robot_messages, decide_every) for key, robot_messages in per_robot.items()],
            now_s,
        )

    def handle_turns(self, turns: Iterable[Turn], now_s: float) -> Outcome:
        """Apply several robots' turns, each as ``handle_batch`` of its messages, one outcome.

        A turn is (robot, its messages in arrival order, its ``decide_every``). The shard
        hands a whole round's plain turns at once: one call, one outcome and one publish for
        many robots instead of one each (the runtime's cost per frame, not the core's).
        """
        outcome = Outcome()
        limit = self._limits.max_batch_frames
        try:
            for key, robot_messages, decide_every in turns:
                self._apply.decide_every = (
                    limit if decide_every is None else max(1, min(decide_every, limit))
                )
                self._handle_robot_safely(key, robot_messages, now_s, outcome)
        finally:
            self._apply.decide_every = limit
        return outcome

    def _handle_robot_safely(
        self, key: RobotKey, messages: list[Frame | SessionEnd], now_s: float, out: Outcome
    ) -> None:
        try:
            self._handle_robot(key, messages, now_s, out)
        except Exception as exc:
            # Rule 6: drop that session (its state is suspect), report it, go on. The
            # outbox logs the traceback.
            out.failures.append((key, exc))
            broken = self._open.pop(key, None)
            if broken is not None:
                self._budgets.set_edges(broken, 0)
            self._holds.discard(key)
            out.reject(
                key[0],
                key[1],
                broken.session if broken else None,
                ErrorCode.INTERNAL,
                f"session reset after an internal error: {type(exc).__name__}",
                None,
            )

    def _handle_robot(
        self, key: RobotKey, messages: list[Frame | SessionEnd], now_s: float, out: Outcome
    ) -> None:
        run: list[Frame] = []  # frames of one session id, in arrival order
        for message in messages:
            if run and message.session != run[0].session:
                self._apply_run(key, run, now_s, out)
                run = []
            if isinstance(message, SessionEnd):
                self._apply_run(key, run, now_s, out)
                run = []
                self._end(key, message, now_s, out)
            else:
                run.append(message)
        self._apply_run(key, run, now_s, out)

    def _apply_run(self, key: RobotKey, run: list[Frame], now_s: float, out: Outcome) -> None:
        if not run:
            return
        session_id = run[0].session
        current = self._open.get(key)
        if current is None and self._durability.resumes:
            current = self._resume(key, out, now_s)
        if current is None or current.session != session_id:
            if (key, session_id) in self._closed:
                self._refuse_on_closed(key, session_id, run, out)
                return
            current = self._open_session(key, session_id, run[0].seq, current, now_s, out)
            if current is None:
                return
        current.last_activity_s = now_s
        self._open.move_to_end(key)
        ordered = sorted(run, key=lambda f: f.seq)
        holds = self._holds
        if holds.max_frames:
            # Lazy on purpose: each frame is routed after the ones before it were applied,
            # so the gap test sees the current last seq.
            marks = self._marks
            self._apply.frames(
                current,
                (f for f in ordered if not holds.held_back(current, f, now_s, out, marks)),
                out,
            )
            self._drain_hold(current, now_s, out)
        else:
            self._apply.frames(current, ordered, out)
        self._checkpoint_if_due(current, now_s, out)

    def _open_session(
        self,
        key: RobotKey,
        session_id: str,
        first_seq: int,
        current: RobotSession | None,
        now_s: float,
        out: Outcome,
    ) -> RobotSession | None:
        """Close the robot's open session, if any, and start ``session_id`` (rule 1)."""
        fleet, robot = key
        if current is not None:
            self._close(key, "replaced", out)
        refusal = self._admission_refusal(fleet, now_s, out)
        if refusal is not None:
            out.reject(fleet, robot, session_id, ErrorCode.SESSION_LIMIT, refusal, first_seq)
            return None
        segmenter = self._segmenting.new_segmenter(fleet)
        session = RobotSession(fleet, robot, session_id, segmenter, now_s)
        self._durability.phase(session, now_s)
        self._open[key] = session
        out.opened.append(session)
        return session

    def _refuse_on_closed(
        self, key: RobotKey, session_id: str, run: list[Frame], out: Outcome
    ) -> None:
        """Frames of a closed session: SESSION_CLOSED, counted on its final state."""
        final = self._final_states.get(key)
        # A copy judged news while the session was open (a probe) can reach the table
        # behind the robot's own put of that frame and its end: a redelivery, uncounted.
        if final is not None and final.session == session_id and final.last_seq is not None:
            last = final.last_seq
            run = [
                f for f in run if not (f.seq <= last and self._marks.take(key, f.session, f.seq))
            ]
        if final is not None and final.session == session_id:
            self._final_states[key] = final.model_copy(
                update={"frames_rejected": final.frames_rejected + len(run)}
            )
        for frame in run:
            out.reject(
                key[0],
                key[1],
                session_id,
                ErrorCode.SESSION_CLOSED,
                f"session {session_id!r} is closed",
                frame.seq,
            )

    def _admission_refusal(self, fleet: str, now_s: float, out: Outcome) -> str | None:
        """Make room for a new session; return why it cannot be opened, or None."""
        refusal = self._budgets.admission_refusal(fleet, now_s)
        if refusal is not None:
            return refusal
        max_sessions = self._limits.max_sessions
        if len(self._open) >= max_sessions and self._store is not None:
            for key in evictable(self._open.items(), now_s):
                self._evict(key, self._open[key], now_s, out)
        if len(self._open) < max_sessions:
            return None
        if self._store is None:
            return f"{len(self._open)} sessions open, the shard limit"
        return (
            f"{len(self._open)} sessions open, the shard limit, none idle for "
            f"{EVICT_MIN_IDLE_S:g} s to evict"
        )

    # -- catch-up (catchup.py) ---------------------------------------------------------------

    def _drain_hold(self, session: RobotSession, now_s: float, out: Outcome) -> None:
        """Apply the held frames that now follow the last seq without a gap."""
        if session.hold_until_s is None:
            return
        self._apply.frames(session, self._holds.contiguous(session), out)
        if not session.held and not tail_awaited(session):
            self._finish_hold(session, now_s, out)
        elif self._holds.overflowing(session):
            # Bounded: the cache is slow or does not hold the gap; stop waiting for it.
            self._release(session, out, now_s)

    def _release(self, session: RobotSession, out: Outcome, now_s: float | None = None) -> None:
        """End a hold: apply what is held in seq order; seqs nobody returned are missing."""
        if session.hold_until_s is None:
            return
        self._apply.frames(session, self._holds.take_all(session), out)
        self._finish_hold(session, now_s, out)

    def _finish_hold(self, session: RobotSession, now_s: float | None, out: Outcome) -> None:
        self._holds.finish(session)
        if session.held_end is not None and now_s is not None:
            end, session.held_end = session.held_end, None
            self._end(session.key, end, now_s, out, ask_cache=False)  # the cache was asked

    def recover(
        self, key: RobotKey, session_id: str, frames: Iterable[Frame], now_s: float
    ) -> Outcome:
        """Take frames a robot's cache returned for a catch-up of ``session_id``."""
        out = Outcome()
        session = self._open.get(key)
        if session is None or session.session != session_id or session.hold_until_s is None:
            return out  # nothing waits for them any more
        self._holds.take_recovered(session, frames, out, self._marks)
        self._drain_hold(session, now_s, out)
        self._checkpoint_if_due(session, now_s, out)
        return out

    def catchup_done(self, key: RobotKey, session_id: str, now_s: float) -> Outcome:
        """The robot's cache has answered (or the query ended): release the hold."""
        out = Outcome()
        session = self._open.get(key)
        if session is not None and session.session == session_id:
            self._release(session, out, now_s)
            self._checkpoint_if_due(session, now_s, out)
        return out

    def release_overdue(self, now_s: float) -> Outcome:
        """Release every hold older than ``catchup_wait_s`` (a cache that never answered)."""
        out = Outcome()
        for session in self._holds.overdue(now_s, self._open):
            self._release(session, out, now_s)
            self._checkpoint_if_due(session, now_s, out)
        return out

    # -- durability (durability.py) ----------------------------------------------------------

    def _checkpoint_if_due(self, session: RobotSession, now_s: float, out: Outcome) -> None:
        # Not when it closed meanwhile (an end after a hold).
        if self._open.get(session.key) is session and self._durability.due(session, now_s):
            self._durability.checkpoint(session, "open", now_s, out, self._closed)

    def _resume(self, key: RobotKey, out: Outcome, now_s: float) -> RobotSession | None:
        session = self._durability.resume(key, out, now_s, self._closed)
        if session is not None:
            self._open[key] = session
            self._budgets.set_edges(session, session.segmenter.memory_edges)
            out.resumed.append(session)
        return session

    @property
    def store_heals(self) -> int:
        """How often the store came back after losing durability (0 without a store)."""
        store = self._store
        return 0 if store is None else store.health.heals

    def checkpoint_open(self, now_s: float) -> Outcome:
        """Checkpoint every open session: the store healed, its file may hold none of them."""
        out = Outcome()
        if self._store is not None:
            for session in list(self._open.values()):
                self._durability.checkpoint(session, "open", now_s, out, self._closed)
        return out

    def expire_idle(self, now_s: float) -> Outcome:
        """Evict (with a store) or close (without) every session idle past the timeout."""
        out = Outcome()
        timeout_s = self._limits.idle_timeout_s
        for key, session in list(self._open.items()):
            if now_s - session.last_activity_s > timeout_s:
                if self._store is None:
                    self._close(key, "idle", out)
                    continue
                # The robot may only be paused: keep its session, free the memory.
                self._evict(key, session, now_s, out)
        return out

    def _evict(self, key: RobotKey, session: RobotSession, now_s: float, out: Outcome) -> None:
        """Move a session to the store (which this table has) and free its memory."""
        self._release(session, out, now_s)
        if self._open.get(key) is not session:
            return  # an end that waited for the catch-up closed it
        self._durability.checkpoint(session, "evicted", now_s, out, self._closed)
        self._drop(key, session)
        out.evicted += 1

    def _drop(self, key: RobotKey, session: RobotSession) -> None:
        del self._open[key]
        self._budgets.set_edges(session, 0)

    # -- closing -----------------------------------------------------------------------------

    def _end(
        self, key: RobotKey, end: SessionEnd, now_s: float, out: Outcome, *, ask_cache: bool = True
    ) -> None:
        current = self._open.get(key)
        if current is None and self._durability.resumes:
            current = self._resume(key, out, now_s)  # it ended while no instance ran
        if current is not None and current.hold_until_s is not None:
            current.held_end = end  # after the held frames: the end waits for the catch-up
            return
        if current is None or current.session != end.session:
            return  # a repeated end, or the end of a session never seen: nothing to close
        expected = current.expected_seq
        if end.last_seq is not None and end.last_seq >= expected:
            if ask_cache and self._holds.max_frames:
                # The tail may wait in the robot's cache (catchup.py, invariant 3): the end
                # closes the session when the catch-up is over.
                self._holds.start(current, now_s, out)
                current.held_end = end
                return
            gap = current.count_gap(expected, end.last_seq)
            report_gap(current, gap, end.last_seq, out)
        self._close(key, "ended", out)

    def _close(self, key: RobotKey, cause: str, out: Outcome) -> None:
        session = self._open[key]
        session.held_end = None
        self._release(session, out)  # frames held for a catch-up are applied, gaps counted
        del self._open[key]
        if session.segmenter.pending_frames:
            self._apply.decide(session, out)
        self._budgets.set_edges(session, 0)
        self._closed.close(key, session.session)
        identity = self._identity
        epoch = identity.epoch_of(session.fleet, session.robot)
        final = session_state(session, identity.instance, is_open=False, epoch=epoch)
        final_graph = self._area_graph_of(session)
        if self._store is not None:
            closed_ids = self._closed.of(key)
            record = self._durability.record(
                session, "closed", closed_ids, final=(final, final_graph)
            )
            out.checkpoints.append((session, record))
        self._final_states[key] = final
        self._final_states.move_to_end(key)
        self._final_graphs[key] = final_graph
        while len(self._final_states) > self._limits.max_sessions:
            gone, _ = self._final_states.popitem(last=False)
            self._final_graphs.pop(gone, None)
        out.closed.append((final, cause))

    def _area_graph_of(self, session: RobotSession) -> AreaGraph:
        epoch = self._identity.epoch_of(session.fleet, session.robot)
        return session_area_graph(session, self._identity.instance, epoch=epoch)

    def close_all(self, cause: str) -> Outcome:
        """Stop: checkpoint every open session (with a store) or close it (without)."""
        out = Outcome()
        for key, session in list(self._open.items()):
            if self._store is None:
                self._close(key, cause, out)
                continue
            # At a stop, held frames are applied and the seqs still missing counted.
            self._release(session, out, session.last_activity_s)
            if self._open.get(key) is not session:
                continue  # an end that waited for the catch-up closed it
            if session.segmenter.pending_frames:
                self._apply.decide(session, out)
            self._durability.checkpoint(session, "open", session.last_activity_s, out, self._closed)
            epoch = self._identity.epoch_of(session.fleet, session.robot)
            out.suspended.append(
                session_state(session, self._identity.instance, is_open=True, epoch=epoch)
            )
            self._drop(key, session)
        return out

    def hand_over(self, leaving: Callable[[str, str], bool], now_s: float) -> Outcome:
        """Checkpoint and drop the sessions of robots whose partition this instance lost.

        Frames held for a catch-up are dropped, not applied: the new owner resumes at the
        checkpoint and fetches them from the robot's cache itself. Nothing is published
        (the fence is already closed for these robots).
        """
        out = Outcome()
        for key, session in list(self._open.items()):
            if not leaving(*key):
                continue
            self._holds.drop(session)
            if self._durability.resumes:  # without a file, the store's shelf carries it
                self._durability.checkpoint(session, "open", now_s, out, self._closed)
            self._drop(key, session)
            out.evicted += 1
        self._closed.forget(leaving)
        self._marks.forget(leaving)
        return out

    def release_robot(self, key: RobotKey) -> MovedRobot | None:
        """Take out all this table keeps of a robot (rule 7); None while a catch-up holds it.

        Its cache marks stay: a cache's copy arriving after the move counts as a duplicate.
        """
        session = self._open.get(key)
        if session is not None and session.hold_until_s is not None:
            return None
        if session is not None:
            self._drop(key, session)
        closed_ids = self._closed.of(key)
        self._closed.forget(lambda fleet, robot: (fleet, robot) == key)
        final = self._final_states.pop(key, None), self._final_graphs.pop(key, None)
        return MovedRobot(key, session, closed_ids, *final)

    def adopt_robot(self, moved: MovedRobot) -> None:
        """Take a robot another table released (rule 7)."""
        key, session = moved.key, moved.session
        if session is not None:
            self._open[key] = session
            self._budgets.set_edges(session, session.segmenter.memory_edges)
        if moved.closed_ids:
            self._closed.remember(key, moved.closed_ids)
        if moved.final_state is not None:
            self._final_states[key] = moved.final_state
        if moved.final_graph is not None:
            self._final_graphs[key] = moved.final_graph

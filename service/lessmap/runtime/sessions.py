"""The robot sessions of one shard: sequencing, coalescing, limits. No Zenoh, no threads.

Rules of this file (the service's ordering contract, schemas/README.md):

1. One open session per (fleet, robot). A frame with a new session id closes the open one
   (its final state goes out) and starts a new CovGraph. Frames of a session closed before
   are rejected (SESSION_CLOSED): a session id is never reopened. A cache's copy of a frame
   the closed session received (``note_from_cache``: a probe judged news while the session
   was open) is a redelivery instead, dropped uncounted.
2. Frames of a session are applied in seq order exactly once. A batch is sorted by seq first,
   so reordering inside a batch loses nothing. seq <= last applied: ignored, counted as
   DUPLICATE_SEQ, or OUT_OF_ORDER when it falls in a gap reported earlier. seq > last + 1:
   the missing frames are counted, SEQ_GAP is reported, and the frame is applied.
7. Exact accounting: every frame a robot puts on its key (well-formed: decoding failures are
   counted by code in the metrics, they name no session) lands in exactly one counter of its
   session: ``frames_applied``, ``frames_duplicate`` (a seq received before, or a cache
   redelivery after a restore), ``frames_rejected`` (OUT_OF_ORDER, GRAPH_LIMIT, INVALID, and
   SESSION_CLOSED on the closed session's state) or ``frames_missing`` (seqs never received).
   A late frame moves its seq from missing to rejected, so nothing is counted twice.
3. Coalescing: ``handle_batch`` applies up to ``max_batch_frames`` frames of a session and
   then decides once; with ``max_batch_frames = 1`` it decides at every frame, exactly as
   ``lessmap segment`` does offline.
4. Limits never grow memory unbounded: at most ``max_sessions`` open sessions per shard and
   ``max_nodes`` features per CovGraph; past either, the message is rejected with an error.
   Work budgets bound what one frame may cost before it reaches the core: at most
   ``max_pairs_per_frame`` pair updates (k features make k(k-1)/2; ``LIMIT_EXCEEDED``),
   at most ``max_edges`` CovGraph edges per session and ``ledger.max_edges_total`` over the
   instance (``GRAPH_LIMIT``), a graph counted by what it holds in edges' worth
   (``Segmenter.memory_edges``: its edges, or a large dense store's bytes at 24 B an edge,
   so the budgets bound memory too). The edge checks are conservative: a frame is counted as if
   every pair of its features were a new edge (a session near its budget may see a frame
   refused that would have added fewer). A refused frame counts as received and rejected.
   New sessions are admitted at ``admission.rate_per_s`` per fleet (a token bucket); when
   the shard is full, sessions idle for ``_EVICT_MIN_IDLE_S`` or more are evicted to the
   store (longest idle first) to make room, and only then is a frame refused
   (``SESSION_LIMIT``).
5. Durable sessions (with a ``CheckpointStore`` that reaches a file): a session is checkpointed
   every ``checkpoint_every_frames`` applied frames or ``checkpoint_interval_s``, whichever
   comes first, when it closes and when the service stops. A session that is not in memory
   is looked up in the store on its next frame and resumes exactly where its checkpoint
   stands (the segmenter's bytes, its counters and gap ranges). Idle sessions are evicted
   to the store instead of being closed. Without a file, idle sessions close as before.
   Frames at or below the seq a session was restored at are redeliveries (a robot's cache
   answering a catch-up query): counted as duplicates, never reported as errors.
   A checkpoint is not saved by the table: it travels in the outcome (``checkpoints``) and
   ``commit_checkpoints`` saves it after the outcome was published, so no checkpoint (kept,
   shipped to a standby, answered to a new owner) ever covers a transition that is not on
   the wire yet. A session with a transition the fence held back (``RobotSession.fenced``)
   is never checkpointed again: the partition's next owner decides those frames anew.
6. Catch-up (``catchup_max_frames > 0``, the service turns it on with a store): a frame
   beyond a gap is not applied at once. It is *held*, with every later frame of the session,
   and the outcome carries a ``CatchupRequest``: the shard asks the robot's publication cache
   for its newest ``catchup_max_frames`` frames. Recovered frames (``recover``) and late
   live ones fill the hold; whatever is contiguous is applied in seq order at once. When the
   cache has answered (``catchup_done``), after ``catchup_wait_s`` (``release_overdue``), or
   when more than ``catchup_max_frames`` frames are held, the hold is released: the held
   frames are applied in seq order and only the seqs no cache returned are reported as
   SEQ_GAP. A ``SessionEnd`` whose ``last_seq`` lies beyond the last seen frame starts a
   catch-up too (once): the end is held until the cache has answered or the hold expires,
   so a tail dropped at a former owner during a hand-over is recovered, not counted missing.
   One catch-up per session at a time, at most one per ``catchup_wait_s``, so a
   robot that skips seqs on purpose costs a bounded number of cache replies. Recovered
   frames that are not needed (already applied, another session, no hold) are dropped
   silently. Held frames are not in a checkpoint: a restart asks the cache for them again.
"""

from __future__ import annotations

import logging
import sqlite3
import time
import zlib
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from lessmap.core import GraphError, PartitionParams
from lessmap.core.areas.tracker import AreaParams
from lessmap.core.segmenter import (
    DEFAULT_METHOD,
    Method,
    make_segmenter,
    segmenter_from_bytes,
)
from lessmap.runtime.budget import pairs_of
from lessmap.runtime.store import SessionRecord
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import (
    AreaGraph,
    AreaNode,
    Frame,
    Passage,
    SessionEnd,
    SessionState,
    SubmapSummary,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from lessmap.core import Submap
    from lessmap.core.areas.graph import AreaGraph as CoreAreaGraph
    from lessmap.core.segmenter import SegmentChange, Segmenter
    from lessmap.runtime.budget import EdgeLedger, SessionAdmission
    from lessmap.runtime.store import CheckpointStore

log = logging.getLogger(__name__)

RobotKey = tuple[str, str]  # (fleet, robot)

_CLOSED_IDS_KEPT = 16  # per robot: enough to reject stragglers of recent sessions
_GAPS_KEPT = 64  # per session: gap ranges remembered to tell OUT_OF_ORDER from DUPLICATE
_EVICT_MIN_IDLE_S = 1.0  # a full shard evicts sessions idle this long to admit a new one
_CACHE_MARKS_KEPT = 4096  # per robot: frames taken from its cache not yet matched by its put
_EVICT_BATCH = 16  # sessions evicted at once when the shard is full (amortizes the scan)
# Cost units of the fair scheduler (shard.py): roughly one pair update each. A frame costs
# its pairs plus a fixed overhead; a decision costs in proportion to the CovGraph's edges
# (measured: ~25 ns per pair update, ~0.25 us per edge and decision).
FRAME_COST = 1000
DECISION_COST_PER_EDGE = 10


@dataclass(frozen=True, slots=True)
class Rejection:
    """An inbound message the table refused, and why (becomes an Error event)."""

    fleet: str
    robot: str
    session: str | None
    code: ErrorCode
    detail: str
    seq: int | None


@dataclass(frozen=True, slots=True)
class CatchupRequest:
    """Ask a robot's publication cache for its newest frames (the shard sends the query)."""

    fleet: str
    robot: str
    session: str
    after_seq: int  # the last seq received in order: the frames after it are wanted
    max_frames: int


@dataclass(slots=True)
class RobotSession:
    """One robot session: its segmenter (the paper's partitioner, or areas) and its counters."""

    fleet: str
    robot: str
    session: str
    segmenter: Segmenter
    last_activity_s: float
    frames_duplicate: int = 0
    frames_missing: int = 0
    frames_rejected: int = 0
    last_seen_seq: int | None = None  # highest seq received, applied or refused
    gaps: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=_GAPS_KEPT))
    restored_seq: int | None = None  # last_seen_seq of the checkpoint it resumed from
    frames_since_checkpoint: int = 0
    checkpoint_s: float = 0.0  # activity time of the last checkpoint
    # Catch-up (rule 6): frames beyond a gap, waiting for the robot's cache to fill it.
    held: dict[int, Frame] = field(default_factory=dict)
    held_end: SessionEnd | None = None  # an end that arrived during the hold
    hold_until_s: float | None = None  # a hold is under way until then
    next_catchup_s: float = 0.0  # no new catch-up query before
    recovered: int = 0  # frames the current hold took from the robot's cache
    edges: int = 0  # upper bound of the CovGraph's edges (exact after a decision)
    fenced: bool = False  # a transition of it was not published (rule 5): never checkpointed

    def counters(self) -> dict[str, Any]:
        """The non-segmenter part of the session, for its checkpoint (JSON-ready)."""
        return {
            "frames_duplicate": self.frames_duplicate,
            "frames_missing": self.frames_missing,
            "frames_rejected": self.frames_rejected,
            "last_seen_seq": self.last_seen_seq,
            "gaps": [list(g) for g in self.gaps],
        }

    def restore_counters(self, meta: dict[str, Any]) -> None:
        """Take back the counters of a checkpoint."""
        self.frames_duplicate = int(meta["frames_duplicate"])
        self.frames_missing = int(meta["frames_missing"])
        self.frames_rejected = int(meta["frames_rejected"])
        seen = meta["last_seen_seq"]
        self.last_seen_seq = self.restored_seq = None if seen is None else int(seen)
        self.gaps.extend((int(lo), int(hi)) for lo, hi in meta["gaps"])

    def state(self, instance: str, *, is_open: bool, epoch: int = 1) -> SessionState:
        """Return the session's state as the wire message."""
        p = self.segmenter
        return SessionState(
            fleet=self.fleet,
            robot=self.robot,
            session=self.session,
            instance=instance,
            epoch=epoch,
            open=is_open,
            last_seq=p.last_seq,
            frames_applied=p.frames_applied,
            frames_duplicate=self.frames_duplicate,
            frames_missing=self.frames_missing,
            frames_rejected=self.frames_rejected,
            transitions=p.transitions,
            method=p.method.wire,
            current_area=p.current_area,
            current_submap=summary_of(p.current_submap()),
            closed_submaps=[summary_of(s) for s in p.closed_submaps],
            nodes=p.node_count,
            edges=p.edge_count,
        )

    def area_graph(self, instance: str, *, epoch: int = 1) -> AreaGraph:
        """Return the session's areas and passages as the wire message."""
        return wire_area_graph(
            self.fleet,
            self.robot,
            self.session,
            self.segmenter.area_graph(),
            method=self.segmenter.method.wire,
            instance=instance,
            epoch=epoch,
        )


def commit_checkpoints(outcome: Outcome, store: CheckpointStore) -> int:
    """Save an outcome's checkpoints (rule 5); call it once the outcome was published.

    Returns how many were withheld: those of sessions with a transition the fence held back.
    """
    withheld = 0
    for session, record in outcome.checkpoints:
        if session.fenced:
            withheld += 1
        else:
            store.save(record)
    outcome.checkpoints.clear()  # committed once, even if published again
    return withheld


def wire_area_graph(
    fleet: str,
    robot: str,
    session: str,
    graph: CoreAreaGraph,
    *,
    method: str,
    instance: str,
    epoch: int,
) -> AreaGraph:
    """Convert a core area graph to the wire message."""
    return AreaGraph(
        fleet=fleet,
        robot=robot,
        session=session,
        instance=instance,
        epoch=epoch,
        method=method,
        areas=[
            AreaNode(
                id=node.area,
                frames=node.frames,
                # A listed area holds frames, so the robot was there at least once.
                visits=max(1, node.visits),
                first_seq=node.first_seq,
                last_seq=node.last_seq,
                features=list(node.features),
            )
            for node in graph.nodes
        ],
        passages=[
            Passage(
                a=edge.a,
                b=edge.b,
                a_to_b=edge.a_to_b,
                b_to_a=edge.b_to_a,
                boundary_features=list(edge.boundary_features),
            )
            for edge in graph.edges
        ],
    )


def summary_of(submap: Submap) -> SubmapSummary:
    """Convert a core submap to its wire summary."""
    return SubmapSummary(
        id=submap.id,
        first_seq=submap.first_seq,
        last_seq=submap.last_seq,
        frame_count=submap.frame_count,
        features=list(submap.features),
    )


@dataclass(slots=True)
class Outcome:
    """What one batch produced, for the transport layer to publish."""

    transitions: list[tuple[RobotSession, SegmentChange]] = field(default_factory=list)
    rejections: list[Rejection] = field(default_factory=list)
    opened: list[RobotSession] = field(default_factory=list)
    resumed: list[RobotSession] = field(default_factory=list)  # restored from the store
    closed: list[tuple[SessionState, str]] = field(default_factory=list)  # (final state, cause)
    suspended: list[SessionState] = field(default_factory=list)  # checkpointed at stop
    evicted: int = 0  # idle sessions moved to the store
    frames_applied: int = 0
    frames_duplicate: int = 0
    frames_missing: int = 0
    frames_late: int = 0  # OUT_OF_ORDER: counted missing when the gap was seen, now rejected
    decisions: list[tuple[float, int]] = field(default_factory=list)  # (seconds, batch frames)
    catchups: list[CatchupRequest] = field(default_factory=list)  # queries for the shard
    frames_recovered: int = 0  # taken from a robot's cache and applied or held
    failures: list[tuple[RobotKey, Exception]] = field(default_factory=list)
    # Records to save once the rest was published (rule 5, ``commit_checkpoints``).
    checkpoints: list[tuple[RobotSession, SessionRecord]] = field(default_factory=list)

    def reject(
        self,
        fleet: str,
        robot: str,
        session: str | None,
        code: ErrorCode,
        detail: str,
        seq: int | None,
    ) -> None:
        """Record a refused (or, for SEQ_GAP, a noted) message."""
        self.rejections.append(Rejection(fleet, robot, session, code, detail, seq))


class SessionTable:
    """The open sessions of one shard and the rules above."""

    def __init__(
        self,
        params: PartitionParams,
        *,
        method: Method = DEFAULT_METHOD,
        area_params: AreaParams | None = None,
        omits_empty_frames: Callable[[str], bool] | None = None,
        max_sessions: int,
        max_nodes: int,
        max_batch_frames: int,
        idle_timeout_s: float,
        instance: str,
        clock: Callable[[], float],
        store: CheckpointStore | None = None,
        checkpoint_every_frames: int = 100,
        checkpoint_interval_s: float = 10.0,
        checkpoint_phase: bool = True,
        catchup_max_frames: int = 0,
        catchup_wait_s: float = 2.0,
        wall_clock: Callable[[], float] = time.time,
        max_pairs_per_frame: int = 0,
        max_edges: int = 0,
        ledger: EdgeLedger | None = None,
        ledger_slot: int = 0,
        admission: SessionAdmission | None = None,
        epoch_of: Callable[[str, str], int] | None = None,
    ) -> None:
        self._params = params
        self._method = method  # of new sessions; a resumed one keeps the method it had
        self._area_params = area_params if area_params is not None else AreaParams()
        # Per fleet: its robots leave out their empty frames, so stamp gaps are blindness.
        self._omits_empty_frames = omits_empty_frames or (lambda _fleet: False)
        # Epoch of a robot's partition at this instance, for states and checkpoints.
        self._epoch_of = epoch_of if epoch_of is not None else (lambda _fleet, _robot: 1)
        self._max_pairs = max_pairs_per_frame  # 0: no budget
        self._max_edges = max_edges  # 0: no budget
        self._ledger = ledger
        self._ledger_slot = ledger_slot
        self._admission = admission
        self._decide_every = max_batch_frames  # this turn's coalescing (``handle_turns``)
        self._catchup_max_frames = catchup_max_frames  # 0: no catch-up, gaps reported at once
        self._catchup_wait_s = catchup_wait_s
        self._holding: set[RobotKey] = set()  # sessions with a hold under way
        # (session, seq) of frames taken from a robot's cache (a catch-up reply, a take-over
        # probe): the robot's own put of the same frame, arriving before or after the copy,
        # is the one offer of that frame, so the second of the two is dropped uncounted.
        self._from_cache: dict[RobotKey, set[tuple[str, int]]] = {}
        self._store = store if store is not None and store.path is not None else None
        self._checkpoint_every_frames = checkpoint_every_frames
        self._checkpoint_interval_s = checkpoint_interval_s
        self._checkpoint_phase = checkpoint_phase
        self._wall_clock = wall_clock
        self._instance = instance
        self._max_sessions = max_sessions
        self._max_nodes = max_nodes
        self._max_batch_frames = max_batch_frames
        self._idle_timeout_s = idle_timeout_s
        self._clock = clock  # only used to time decisions; activity time is passed in
        # Least recently active first: a full shard evicts from the front.
        self._open: OrderedDict[RobotKey, RobotSession] = OrderedDict()
        self._closed_ids: OrderedDict[RobotKey, deque[str]] = OrderedDict()
        # Closed sessions leave only their final state (the CovGraph is freed), kept for
        # state and submap queries until max_sessions newer ones push it out.
        self._final_states: OrderedDict[RobotKey, SessionState] = OrderedDict()
        self._final_graphs: dict[RobotKey, AreaGraph] = {}  # the same robots' area graphs

    def __len__(self) -> int:
        return len(self._open)

    def robots(self) -> list[RobotKey]:
        """Every robot with an open or remembered closed session."""
        return list(dict.fromkeys([*self._open, *self._final_states]))

    def knows(self, fleet: str, robot: str) -> bool:
        """Whether the robot is one of ``robots()`` (an open or remembered closed session)."""
        key = (fleet, robot)
        return key in self._open or key in self._final_states

    def note_from_cache(self, key: RobotKey, session_id: str, seq: int) -> None:
        """Remember that frame ``seq`` of a session came (or comes) from the robot's cache."""
        marks = self._from_cache.setdefault(key, set())
        if len(marks) >= _CACHE_MARKS_KEPT:
            marks.clear()  # bounded; a forgotten mark only makes a late duplicate counted
        marks.add((session_id, seq))

    def _cache_copy(self, session: RobotSession, seq: int) -> bool:
        """True (and the mark is used up) when one of two copies of a frame came from a cache."""
        return self._use_mark((session.fleet, session.robot), session.session, seq)

    def _use_mark(self, key: RobotKey, session_id: str, seq: int) -> bool:
        marks = self._from_cache.get(key)
        if not marks or (session_id, seq) not in marks:
            return False
        marks.discard((session_id, seq))
        if not marks:
            del self._from_cache[key]
        return True

    def _cache_copy_of_closed(self, key: RobotKey, frame: Frame) -> bool:
        """True (the mark used up) for a cache's copy of a frame its closed session received.

        A copy judged news while the session was open (a probe, ``is_news``) can reach the
        table behind the robot's own put of that frame and its end: the frame was applied
        once, so the copy is a redelivery, dropped uncounted, never a SESSION_CLOSED.
        """
        final = self._final_states.get(key)
        if final is None or final.session != frame.session or final.last_seq is None:
            return False
        return frame.seq <= final.last_seq and self._use_mark(key, frame.session, frame.seq)

    def is_news(self, fleet: str, robot: str, message: Frame | SessionEnd) -> bool:
        """True when a message found in a robot's cache is not known here yet.

        For the probe of a partition just taken over (``Service._probe_caches``) and the
        frames held while it was handed over: news is a frame of an unknown session or above
        the last seq seen (in memory, else in the store), or the end of a session open here
        (applied, it would have closed it); anything else is dropped without being counted,
        since it was counted when it first arrived.
        """
        key = (fleet, robot)
        if message.session in self._closed_ids.get(key, ()):
            return False
        session = self._open.get(key)
        if session is not None:
            if session.session != message.session:
                return isinstance(message, Frame)
            seen = session.last_seen_seq
        elif self._store is not None:
            try:
                record = self._store.load(key)
            except sqlite3.Error:
                record = None
            if record is None or record.session != message.session:
                return isinstance(message, Frame)
            if record.status == "closed":
                return False
            seen = record.last_seq
        else:
            return isinstance(message, Frame)
        if isinstance(message, SessionEnd):
            return True
        return seen is None or message.seq > seen

    def state(self, fleet: str, robot: str) -> SessionState | None:
        """Return the state of a robot's open session, else of its last closed one."""
        key = (fleet, robot)
        session = self._open.get(key)
        if session is not None:
            return session.state(
                self._instance, is_open=True, epoch=self._epoch_of(session.fleet, session.robot)
            )
        final = self._final_states.get(key)
        if final is not None or self._store is None:
            return final
        try:
            record = self._store.load(key)
        except sqlite3.Error:
            return None
        if record is None or "state" not in record.meta:
            return None
        return SessionState.model_validate(record.meta["state"])

    def area_graph(self, fleet: str, robot: str) -> AreaGraph | None:
        """Return the area graph of a robot's open session, else of its last closed one."""
        key = (fleet, robot)
        session = self._open.get(key)
        if session is not None:
            return session.area_graph(self._instance, epoch=self._epoch_of(fleet, robot))
        final = self._final_graphs.get(key)
        if final is not None or self._store is None:
            return final
        try:
            record = self._store.load(key)
        except sqlite3.Error:
            return None
        if record is None:
            return None
        if "area_graph" in record.meta:  # closed
            return AreaGraph.model_validate(record.meta["area_graph"])
        if record.snapshot is None:
            return None
        try:  # an evicted session: its graph is in its snapshot
            segmenter = segmenter_from_bytes(record.snapshot)
        except GraphError as exc:
            log.warning("checkpoint of %s/%s unreadable for its areas: %s", fleet, robot, exc)
            return None
        return wire_area_graph(
            fleet,
            robot,
            record.session,
            segmenter.area_graph(),
            method=segmenter.method.wire,
            instance=self._instance,
            epoch=self._epoch_of(fleet, robot),
        )

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

    # -- batch -----------------------------------------------------------------------------

    def decision_cost(self, key: RobotKey) -> int:
        """Estimated cost of one decision of a robot's session, in scheduler cost units."""
        session = self._open.get(key)
        edges = 0 if session is None else session.edges
        return FRAME_COST + DECISION_COST_PER_EDGE * edges

    @property
    def edges(self) -> int:
        """Edges held by this table's sessions (an upper bound)."""
        return sum(s.edges for s in self._open.values())

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

    def handle_turns(
        self,
        turns: Iterable[tuple[RobotKey, list[Frame | SessionEnd], int | None]],
        now_s: float,
    ) -> Outcome:
        """Apply several robots' turns, each as ``handle_batch`` of its messages, one outcome.

        A turn is (robot, its messages in arrival order, its ``decide_every``: it lowers the
        coalescing, never raises it above ``max_batch_frames``). The shard
        hands a whole round's plain turns at once: one call, one outcome and one publish for
        many robots instead of one each (the runtime's cost per frame, not the core's).
        """
        outcome = Outcome()
        limit = self._max_batch_frames
        try:
            for key, robot_messages, decide_every in turns:
                self._decide_every = (
                    limit if decide_every is None else max(1, min(decide_every, limit))
                )
                self._handle_robot_safely(key, robot_messages, now_s, outcome)
        finally:
            self._decide_every = limit
        return outcome

    def _handle_robot_safely(
        self, key: RobotKey, messages: list[Frame | SessionEnd], now_s: float, out: Outcome
    ) -> None:
        try:
            self._handle_robot(key, messages, now_s, out)
        except Exception as exc:
            # A bug in one session must not stop the others: drop that session (its
            # state is suspect), report it, go on. The shard logs the traceback.
            out.failures.append((key, exc))
            broken = self._open.pop(key, None)
            if broken is not None:
                self._set_edges(broken, 0)
            self._holding.discard(key)
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
        fleet, robot = key
        session_id = run[0].session
        current = self._open.get(key)
        if current is None and self._store is not None:
            current = self._resume(key, out, now_s)
        if current is None or current.session != session_id:
            if session_id in self._closed_ids.get(key, ()):
                run = [f for f in run if not self._cache_copy_of_closed(key, f)]
                self._count_on_closed(key, session_id, len(run))
                for frame in run:
                    out.reject(
                        fleet,
                        robot,
                        session_id,
                        ErrorCode.SESSION_CLOSED,
                        f"session {session_id!r} is closed",
                        frame.seq,
                    )
                return
            if current is not None:
                self._close(key, "replaced", out)
            refusal = self._admit(fleet, now_s, out)
            if refusal is not None:
                out.reject(fleet, robot, session_id, ErrorCode.SESSION_LIMIT, refusal, run[0].seq)
                return
            omitted = self._omits_empty_frames(fleet)
            areas = self._area_params.for_stream(empty_frames_omitted=omitted)
            segmenter = make_segmenter(self._method, self._params, areas)
            current = RobotSession(fleet, robot, session_id, segmenter, now_s)
            self._phase_checkpoints(current, now_s)
            self._open[key] = current
            out.opened.append(current)
        current.last_activity_s = now_s
        self._open.move_to_end(key)
        ordered = sorted(run, key=lambda f: f.seq)
        if self._catchup_max_frames:
            # Lazy on purpose: each frame is routed after the ones before it were applied,
            # so the gap test sees the current last seq.
            self._apply_frames(
                current, (f for f in ordered if not self._held_back(current, f, now_s, out)), out
            )
            self._drain_hold(current, now_s, out)
        else:
            self._apply_frames(current, ordered, out)
        self._checkpoint_if_due(current, now_s, out)

    def _admit(self, fleet: str, now_s: float, out: Outcome) -> str | None:
        """Make room for a new session; return why it cannot be opened, or None."""
        if self._admission is not None and not self._admission.allow(fleet, now_s):
            return (
                f"fleet {fleet!r} opens more than {self._admission.rate_per_s:g} new sessions "
                f"a second (burst {self._admission.burst}); retry later"
            )
        if len(self._open) >= self._max_sessions and self._store is not None:
            # Longest idle first (``_open`` is in activity order); never one that is busy.
            for key, session in list(self._open.items())[:_EVICT_BATCH]:
                if now_s - session.last_activity_s < _EVICT_MIN_IDLE_S:
                    break
                self._evict(key, session, now_s, out)
        if len(self._open) >= self._max_sessions:
            return (
                f"{len(self._open)} sessions open, the shard limit, none idle for "
                f"{_EVICT_MIN_IDLE_S:g} s to evict"
                if self._store is not None
                else f"{len(self._open)} sessions open, the shard limit"
            )
        return None

    def _set_edges(self, session: RobotSession, edges: int) -> None:
        """Record a session's edges (0 when it leaves memory) in the instance's ledger."""
        if self._ledger is not None:
            self._ledger.add(self._ledger_slot, edges - session.edges)
        session.edges = edges

    def _apply_frames(self, session: RobotSession, frames: Iterable[Frame], out: Outcome) -> None:
        """Apply frames (ascending seq) and decide every ``max_batch_frames`` applied."""
        pending = 0
        for frame in frames:
            if self._apply_frame(session, frame, out):
                pending += 1
                session.frames_since_checkpoint += 1
                if pending >= self._decide_every:
                    self._decide(session, out)
                    pending = 0
        if pending:
            self._decide(session, out)

    def _checkpoint_if_due(self, session: RobotSession, now_s: float, out: Outcome) -> None:
        key = (session.fleet, session.robot)
        if (
            self._store is not None
            and self._open.get(key) is session  # not closed meanwhile (an end after a hold)
            and (
                session.frames_since_checkpoint >= self._checkpoint_every_frames
                or (
                    session.frames_since_checkpoint
                    and now_s - session.checkpoint_s >= self._checkpoint_interval_s
                )
            )
        ):
            self._checkpoint(session, "open", now_s, out)

    # -- catch-up (rule 6) -----------------------------------------------------------------

    def _held_back(self, session: RobotSession, frame: Frame, now_s: float, out: Outcome) -> bool:
        """Hold a frame that lies beyond a gap (starting a catch-up); False: apply it now."""
        seen = session.last_seen_seq
        if seen is not None and frame.seq <= seen:
            return False  # a duplicate: ``_apply_frame`` reports it
        if session.hold_until_s is None:
            expected = 0 if seen is None else seen + 1
            if frame.seq == expected or now_s < session.next_catchup_s:
                return False
            self._start_catchup(session, now_s, out)
        if frame.seq in session.held:
            if self._cache_copy(session, frame.seq):
                return True
            session.frames_duplicate += 1
            out.frames_duplicate += 1
            out.reject(
                session.fleet,
                session.robot,
                session.session,
                ErrorCode.DUPLICATE_SEQ,
                f"frame {frame.seq} was already received (held for catch-up)",
                frame.seq,
            )
            return True
        session.held[frame.seq] = frame  # past catchup_max_frames, _drain_hold releases
        return True

    def _start_catchup(self, session: RobotSession, now_s: float, out: Outcome) -> None:
        """Hold the session and ask the robot's cache for the frames after the last seen."""
        seen = session.last_seen_seq
        session.hold_until_s = now_s + self._catchup_wait_s
        session.next_catchup_s = now_s + self._catchup_wait_s
        session.recovered = 0
        self._holding.add((session.fleet, session.robot))
        out.catchups.append(
            CatchupRequest(
                session.fleet,
                session.robot,
                session.session,
                -1 if seen is None else seen,
                self._catchup_max_frames,
            )
        )

    def _drain_hold(self, session: RobotSession, now_s: float, out: Outcome) -> None:
        """Apply the held frames that now follow the last seq without a gap."""
        if session.hold_until_s is None:
            return
        seen = session.last_seen_seq
        expected = 0 if seen is None else seen + 1
        run: list[Frame] = []
        while expected in session.held:
            run.append(session.held.pop(expected))
            expected += 1
        self._apply_frames(session, run, out)
        if not session.held and not self._tail_awaited(session):
            self._finish_hold(session, now_s, out)
        elif len(session.held) > self._catchup_max_frames:
            # Bounded: the cache is slow or does not hold the gap; stop waiting for it.
            self._release(session, out, now_s)

    @staticmethod
    def _tail_awaited(session: RobotSession) -> bool:
        """True while a held end names frames not seen yet: the cache's reply may bring more."""
        end = session.held_end
        seen = session.last_seen_seq
        if end is None or end.last_seq is None:
            return False
        return seen is None or seen < end.last_seq

    def _release(self, session: RobotSession, out: Outcome, now_s: float | None = None) -> None:
        """End a hold: apply what is held in seq order; seqs nobody returned are missing."""
        if session.hold_until_s is None:
            return
        held = [session.held[seq] for seq in sorted(session.held)]
        session.held.clear()
        self._apply_frames(session, held, out)
        self._finish_hold(session, now_s, out)

    def _finish_hold(self, session: RobotSession, now_s: float | None, out: Outcome) -> None:
        session.hold_until_s = None
        key = (session.fleet, session.robot)
        self._holding.discard(key)
        log.info(
            "%s/%s %s: caught up to seq %s, %d frame(s) recovered from the robot's cache",
            session.fleet,
            session.robot,
            session.session,
            session.last_seen_seq,
            session.recovered,
        )
        if session.held_end is not None and now_s is not None:
            end, session.held_end = session.held_end, None
            self._end(key, end, now_s, out, ask_cache=False)  # the cache was asked: done

    def recover(
        self, key: RobotKey, session_id: str, frames: Iterable[Frame], now_s: float
    ) -> Outcome:
        """Take frames a robot's cache returned for a catch-up of ``session_id``."""
        out = Outcome()
        session = self._open.get(key)
        if session is None or session.session != session_id or session.hold_until_s is None:
            return out  # nothing waits for them any more
        seen = session.last_seen_seq
        for frame in frames:
            if (
                frame.session != session_id
                or (seen is not None and frame.seq <= seen)
                or frame.seq in session.held
                or len(session.held) >= 2 * self._catchup_max_frames
            ):
                continue  # not needed: silently dropped, never an error
            session.held[frame.seq] = frame
            self.note_from_cache(key, session_id, frame.seq)
            session.recovered += 1
            out.frames_recovered += 1
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
        for key in list(self._holding):
            session = self._open.get(key)
            if session is None:
                self._holding.discard(key)
            elif session.hold_until_s is not None and now_s >= session.hold_until_s:
                self._release(session, out, now_s)
                self._checkpoint_if_due(session, now_s, out)
        return out

    @property
    def holds(self) -> int:
        """Sessions waiting for a catch-up."""
        return len(self._holding)

    # -- durable sessions ------------------------------------------------------------------

    def _record(
        self,
        session: RobotSession,
        status: str,
        *,
        is_open: bool,
        final_graph: AreaGraph | None = None,
    ) -> SessionRecord:
        closed_ids = list(self._closed_ids.get((session.fleet, session.robot), ()))
        keep_graph = status != "closed"
        epoch = self._epoch_of(session.fleet, session.robot)
        # A closed session keeps no snapshot: its area graph is stored for queries instead.
        graph = {} if final_graph is None else {"area_graph": final_graph.model_dump(mode="json")}
        return SessionRecord(
            fleet=session.fleet,
            robot=session.robot,
            session=session.session,
            status=status,
            last_seq=session.last_seen_seq,
            meta={
                **session.counters(),
                "closed_ids": closed_ids,
                "epoch": epoch,
                "state": session.state(self._instance, is_open=is_open, epoch=epoch).model_dump(
                    mode="json"
                ),
                **graph,
            },
            snapshot=session.segmenter.to_bytes() if keep_graph else None,
            updated_s=self._wall_clock(),
        )

    def _phase_checkpoints(self, session: RobotSession, now_s: float) -> None:
        """Start a session's checkpoint clock at a phase of its own.

        Robots of a fleet usually start together and run at one rate: without a phase, all
        their checkpoints fall due in the same instant, and the burst (a snapshot each, on
        the worker) showed as ~90 ms of p99 latency at 200 robots. The phase comes from the
        robot's name (crc32), so it is the same in every run; the first checkpoint of a
        session comes that much earlier, later ones keep the spacing.
        """
        phase = 0.0
        if self._checkpoint_phase:
            phase = zlib.crc32(f"{session.fleet}/{session.robot}".encode()) / 2**32
        session.frames_since_checkpoint = int(phase * self._checkpoint_every_frames)
        session.checkpoint_s = now_s - phase * self._checkpoint_interval_s

    def _checkpoint(self, session: RobotSession, status: str, now_s: float, out: Outcome) -> None:
        assert self._store is not None
        out.checkpoints.append((session, self._record(session, status, is_open=True)))
        session.frames_since_checkpoint = 0
        session.checkpoint_s = now_s

    def _resume(self, key: RobotKey, out: Outcome, now_s: float) -> RobotSession | None:
        """Bring a robot's checkpointed session back into memory, if the store has one."""
        assert self._store is not None
        fleet, robot = key
        # A record of this outcome is not saved yet (an eviction earlier in the same batch).
        record = next((r for _s, r in reversed(out.checkpoints) if r.key == key), None)
        try:
            if record is None:
                record = self._store.load(key)
        except sqlite3.Error as exc:
            out.reject(
                fleet, robot, None, ErrorCode.INTERNAL, f"state store unreadable: {exc}", None
            )
            return None
        if record is None:
            return None
        ids = self._closed_ids.setdefault(key, deque(maxlen=_CLOSED_IDS_KEPT))
        for closed_id in record.meta.get("closed_ids", ()):
            if closed_id not in ids:
                ids.append(closed_id)
        if record.status == "closed":
            if record.session not in ids:
                ids.append(record.session)
            return None
        if record.session in ids:
            # An open record of a session known closed is stale: the store can hand back an
            # older row while its writer holds the newest batch. Reopening it would apply a
            # straggler to a closed session and overwrite its final state.
            log.debug("stale open record of closed session %s/%s %s", fleet, robot, record.session)
            return None
        try:
            assert record.snapshot is not None, "an open record without a snapshot"
            segmenter = segmenter_from_bytes(record.snapshot)
            session = RobotSession(fleet, robot, record.session, segmenter, now_s)
            session.restore_counters(record.meta)
        except Exception as exc:  # a damaged checkpoint must cost only its own session
            log.error("checkpoint of %s/%s %s unreadable: %s", fleet, robot, record.session, exc)
            out.reject(
                fleet,
                robot,
                record.session,
                ErrorCode.INTERNAL,
                f"checkpoint unreadable ({type(exc).__name__}); the session starts fresh",
                None,
            )
            self._store.delete(key)
            return None
        self._phase_checkpoints(session, now_s)
        self._open[key] = session
        self._set_edges(session, segmenter.memory_edges)
        out.resumed.append(session)
        return session

    def _apply_frame(self, session: RobotSession, frame: Frame, out: Outcome) -> bool:
        p = session.segmenter
        seen = session.last_seen_seq
        if seen is not None and frame.seq <= seen:
            if self._cache_copy(session, frame.seq):
                return False
            if session.restored_seq is not None and frame.seq <= session.restored_seq:
                # A redelivery from the robot's cache after a restore.
                session.frames_duplicate += 1
                out.frames_duplicate += 1
                return False
            late = _take_from_gaps(session.gaps, frame.seq)
            if late:
                # Counted once: its slot leaves "missing" for "rejected" (rule 7).
                session.frames_missing -= 1
                session.frames_rejected += 1
                out.frames_late += 1
            else:
                session.frames_duplicate += 1
                out.frames_duplicate += 1
            code = ErrorCode.OUT_OF_ORDER if late else ErrorCode.DUPLICATE_SEQ
            what = "arrived after later frames" if late else "was already received"
            out.reject(
                session.fleet,
                session.robot,
                session.session,
                code,
                f"frame {frame.seq} {what} (last received {seen})",
                frame.seq,
            )
            return False
        # From here on the seq counts as received, applied or not: a refused frame is
        # rejected once, never also reported missing.
        expected = 0 if seen is None else seen + 1
        session.last_seen_seq = frame.seq
        if frame.seq > expected:
            self._count_gap(session, expected, frame.seq - 1, frame.seq, out)
        refusal = self._over_budget(session, len(frame.features))
        if refusal is not None:
            session.frames_rejected += 1
            out.reject(session.fleet, session.robot, session.session, *refusal, frame.seq)
            return False
        if p.node_count + len(frame.features) > self._max_nodes and (
            p.node_count + sum(1 for f in set(frame.features) if not p.feature_known(f))
            > self._max_nodes
        ):  # counting the new features only when the cheap bound says it could matter
            session.frames_rejected += 1
            out.reject(
                session.fleet,
                session.robot,
                session.session,
                ErrorCode.GRAPH_LIMIT,
                f"CovGraph would exceed {self._max_nodes} features",
                frame.seq,
            )
            return False
        try:
            p.apply(frame.seq, frame.stamp_s, frame.features)
        except GraphError as exc:
            session.frames_rejected += 1
            out.reject(
                session.fleet,
                session.robot,
                session.session,
                ErrorCode.INVALID,
                str(exc),
                frame.seq,
            )
            return False
        if self._max_edges or self._ledger is not None:
            self._set_edges(session, session.edges + pairs_of(len(frame.features)))
        out.frames_applied += 1
        return True

    def _over_budget(self, session: RobotSession, features: int) -> tuple[ErrorCode, str] | None:
        """Check a frame of ``features`` features against the work budgets (cheap bounds).

        The bounds count every pair as a new edge; only when a bound says the frame could
        break a budget is the session's exact edge count read (which merges pending pairs)
        and the check repeated.
        """
        pairs = pairs_of(features)
        if self._max_pairs and pairs > self._max_pairs:
            return (
                ErrorCode.LIMIT_EXCEEDED,
                f"{features} features make {pairs} feature pairs, over the budget "
                f"max_pairs_per_frame={self._max_pairs}",
            )
        ledger = self._ledger
        if not self._max_edges and ledger is None:
            return None
        if (self._max_edges and session.edges + pairs > self._max_edges) or (
            ledger is not None and ledger.total() + pairs > ledger.max_edges_total
        ):
            self._set_edges(session, session.segmenter.memory_edges)
            if self._max_edges and session.edges + pairs > self._max_edges:
                return (
                    ErrorCode.GRAPH_LIMIT,
                    f"CovGraph holds {session.edges} edges' worth; a frame of {features} features "
                    f"could add {pairs}, over the budget max_edges_per_session={self._max_edges}",
                )
            if ledger is not None and ledger.total() + pairs > ledger.max_edges_total:
                return (
                    ErrorCode.GRAPH_LIMIT,
                    f"the instance holds {ledger.total()} edges; a frame of {features} features "
                    f"could add {pairs}, over the budget "
                    f"max_edges_total={ledger.max_edges_total}",
                )
        return None

    @staticmethod
    def _count_gap(
        session: RobotSession, first: int, last: int, seq: int | None, out: Outcome
    ) -> None:
        missing = last - first + 1
        session.frames_missing += missing
        session.gaps.append((first, last))
        out.frames_missing += missing
        out.reject(
            session.fleet,
            session.robot,
            session.session,
            ErrorCode.SEQ_GAP,
            f"{missing} frame(s) missing: {first}..{last}",
            seq,
        )

    def _decide(self, session: RobotSession, out: Outcome) -> None:
        batch = session.segmenter.pending_frames
        started = self._clock()
        changes = session.segmenter.decide()
        out.decisions.append((self._clock() - started, batch))
        if self._max_edges or self._ledger is not None:
            self._set_edges(session, session.segmenter.memory_edges)
        out.transitions.extend((session, change) for change in changes)

    def _count_on_closed(self, key: RobotKey, session_id: str, frames: int) -> None:
        """Count frames refused as SESSION_CLOSED on the closed session's final state."""
        final = self._final_states.get(key)
        if final is not None and final.session == session_id:
            self._final_states[key] = final.model_copy(
                update={"frames_rejected": final.frames_rejected + frames}
            )

    # -- closing ---------------------------------------------------------------------------

    def _end(
        self, key: RobotKey, end: SessionEnd, now_s: float, out: Outcome, *, ask_cache: bool = True
    ) -> None:
        current = self._open.get(key)
        if current is None and self._store is not None:
            current = self._resume(key, out, now_s)  # it ended while no instance ran
        if current is not None and current.hold_until_s is not None:
            current.held_end = end  # after the held frames: the end waits for the catch-up
            return
        if current is None or current.session != end.session:
            return  # a repeated end, or the end of a session never seen: nothing to close
        seen = current.last_seen_seq
        expected = 0 if seen is None else seen + 1
        if end.last_seq is not None and end.last_seq >= expected:
            if ask_cache and self._catchup_max_frames:
                # The tail may wait in the robot's cache: frames dropped at a former owner
                # when the partition moved, or lost on the way, while the end came through.
                # Ask for them first; the end closes the session when the catch-up is over,
                # and only what the cache cannot give is counted missing then.
                self._start_catchup(current, now_s, out)
                current.held_end = end
                return
            self._count_gap(current, expected, end.last_seq, end.last_seq, out)
        self._close(key, "ended", out)

    def _close(self, key: RobotKey, cause: str, out: Outcome) -> None:
        session = self._open[key]
        session.held_end = None
        self._release(session, out)  # frames held for a catch-up are applied, gaps counted
        del self._open[key]
        if session.segmenter.pending_frames:
            self._decide(session, out)
        self._set_edges(session, 0)
        ids = self._closed_ids.setdefault(key, deque(maxlen=_CLOSED_IDS_KEPT))
        ids.append(session.session)
        self._closed_ids.move_to_end(key)
        while len(self._closed_ids) > 4 * self._max_sessions:
            self._closed_ids.popitem(last=False)
        final = session.state(
            self._instance, is_open=False, epoch=self._epoch_of(session.fleet, session.robot)
        )
        final_graph = self._final_graph(session)
        if self._store is not None:
            record = self._record(session, "closed", is_open=False, final_graph=final_graph)
            out.checkpoints.append((session, record))
        self._final_states[key] = final
        self._final_states.move_to_end(key)
        self._final_graphs[key] = final_graph
        while len(self._final_states) > self._max_sessions:
            gone, _ = self._final_states.popitem(last=False)
            self._final_graphs.pop(gone, None)
        out.closed.append((final, cause))

    def _final_graph(self, session: RobotSession) -> AreaGraph:
        epoch = self._epoch_of(session.fleet, session.robot)
        return session.area_graph(self._instance, epoch=epoch)

    def expire_idle(self, now_s: float) -> Outcome:
        """Evict (with a store) or close (without) every session idle past the timeout."""
        out = Outcome()
        for key, session in list(self._open.items()):
            if now_s - session.last_activity_s > self._idle_timeout_s:
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
        self._checkpoint(session, "evicted", now_s, out)
        del self._open[key]
        self._set_edges(session, 0)
        out.evicted += 1

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
                self._decide(session, out)
            self._checkpoint(session, "open", session.last_activity_s, out)
            epoch = self._epoch_of(session.fleet, session.robot)
            out.suspended.append(session.state(self._instance, is_open=True, epoch=epoch))
            del self._open[key]
            self._set_edges(session, 0)
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
            session.held.clear()
            session.held_end = None
            session.hold_until_s = None
            self._holding.discard(key)
            if self._store is not None:
                self._checkpoint(session, "open", now_s, out)
            del self._open[key]
            self._set_edges(session, 0)
            out.evicted += 1
        for key in [k for k in self._closed_ids if leaving(*k)]:
            del self._closed_ids[key]
        for key in [k for k in self._from_cache if leaving(*k)]:
            del self._from_cache[key]
        return out


def _take_from_gaps(gaps: deque[tuple[int, int]], seq: int) -> bool:
    """Remove ``seq`` from the reported gap ranges; True when it was in one (a late frame)."""
    for index, (lo, hi) in enumerate(gaps):
        if lo <= seq <= hi:
            del gaps[index]
            # Both halves go back where the range was; a full deque drops its oldest range,
            # and a late frame of a forgotten range then counts as a duplicate.
            for part in ((seq + 1, hi), (lo, seq - 1)):
                if part[0] <= part[1]:
                    gaps.insert(index, part)
            return True
    return False

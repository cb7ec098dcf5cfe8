"""The query server: state, areas, submaps, health and checkpoint queries, on one thread.

Invariants:

1. Zenoh's callback only enqueues a query; the ``lessmap-queries`` thread answers it.
2. A session table is read only by its shard's worker: the query thread sends each shard a
   read (``Shard.read``) and waits for its ``Future``, then encodes and replies itself.
3. Robots of partitions this instance does not own (handed over, or frozen) are not
   answered: their owner answers. Robots only the store knows (closed before a restart,
   evicted, or whose records came with a partition taken over) are answered from it.
4. A query that names one fleet and robot without wildcards asks that robot's shard alone.
"""

from __future__ import annotations

import logging
import queue
import sqlite3
import threading
import time
from concurrent.futures import Future, TimeoutError as FutureTimeout
from typing import TYPE_CHECKING

import zenoh

from lessmap import __version__
from lessmap.runtime.receiver import shard_index
from lessmap.runtime.replies import fit_area_graph, fit_state
from lessmap_schemas import keys
from lessmap_schemas.codec import encode, encoding
from lessmap_schemas.messages import AreaGraph, Health, SessionState, Submap

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from lessmap.config.settings import ServiceSettings
    from lessmap.runtime.metrics import ServiceMetrics
    from lessmap.runtime.ownership import Ownership
    from lessmap.runtime.replication import Replication
    from lessmap.runtime.sessions.table import SessionTable
    from lessmap.runtime.shard import Shard
    from lessmap_schemas.limits import WireLimits

log = logging.getLogger(__name__)

_CUTS_LOGGED = 10_000  # robots whose cut replies were logged (then the set starts again)
_READ_WAIT_S = 30.0  # a shard that does not answer a read within this is left out

Answer = SessionState | AreaGraph | None
RobotAnswers = list[tuple[str, str, Answer]]


class QueryServer:
    """Answers the service's queryables from the shards (each through its worker)."""

    def __init__(
        self,
        settings: ServiceSettings,
        shards: Sequence[Shard],
        ownership: Ownership,
        replication: Replication,
        metrics: ServiceMetrics,
        frames_applied: Callable[[], int],
    ) -> None:
        self._settings = settings
        self._shards = tuple(shards)
        self._ownership = ownership
        self._replication = replication
        self._metrics = metrics
        self._frames_applied = frames_applied
        # Replies are cut to what readers accept (``replies``): the service's own limits.
        self._reply_limits: WireLimits = settings.limits.wire_limits()
        self._cuts_logged: set[tuple[str, str, str]] = set()
        self._started_s = time.monotonic()
        self._queries: queue.SimpleQueue[zenoh.Query | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="lessmap-queries", daemon=True)

    def put(self, query: zenoh.Query) -> None:
        """The queryables' callback (Zenoh's thread): enqueue only."""
        self._queries.put(query)

    def start(self) -> None:
        """Start the query thread."""
        self._thread.start()

    def stop(self) -> None:
        """Answer what is queued, then end the thread (bounded)."""
        self._queries.put(None)
        if self._thread.is_alive():
            self._thread.join(1.0)

    def _run(self) -> None:
        while True:
            query = self._queries.get()
            if query is None:
                return
            try:
                with query:
                    self._answer(query)
            except Exception:
                log.exception("query %s failed", query.selector)

    def _answer(self, query: zenoh.Query) -> None:
        selector = query.key_expr
        text = str(selector)
        if text.startswith(f"{keys.KEY_PREFIX}/@/health/"):
            self._reply_health(query)
            return
        if text.startswith(f"{keys.KEY_PREFIX}/@/checkpoints/"):
            self._replication.reply(query)
            return
        kind = "submaps" if "/submaps/" in text else "areas" if text.endswith("/areas") else "state"
        named_fleet, named_robot = named_fleet_and_robot(text)
        answered: set[tuple[str, str]] = set()
        if named_fleet is not None and named_robot is not None:
            # One robot named (robots poll their own state while they close, apps ask for
            # one robot): only its shard can hold it (invariant 4).
            known, answers = self._read(
                [self._shard_of(named_fleet, named_robot)],
                query,
                kind,
                [(named_fleet, named_robot)],
            )
            if known:
                self._reply(query, kind, answers)
                return
        else:
            known, answers = self._read(self._shards, query, kind, None)
            answered.update(known)
            self._reply(query, kind, answers)
        # Robots known only from the store: the table answers from their record.
        stored = self._stored_robots(selector, answered)
        by_shard: dict[int, list[tuple[str, str]]] = {}
        for fleet, robot in stored:
            by_shard.setdefault(self._index_of(fleet, robot), []).append((fleet, robot))
        for index, robots in by_shard.items():
            _known, answers = self._read([self._shards[index]], query, kind, robots, known=False)
            self._reply(query, kind, answers)

    def _read(
        self,
        shards: Sequence[Shard],
        query: zenoh.Query,
        kind: str,
        robots: list[tuple[str, str]] | None,
        *,
        known: bool = True,
    ) -> tuple[list[tuple[str, str]], RobotAnswers]:
        """Ask shards for the robots' answers (``robots``: these; None: every robot known).

        With ``known``, only robots the table knows (in memory) are answered. Returns the
        robots the tables knew and the answers, in shard order.
        """
        wanted = self._wanted(query, kind)
        state_wanted = kind != "areas"

        def read(table: SessionTable) -> tuple[list[tuple[str, str]], RobotAnswers]:
            if robots is None:
                names = table.robots()
            elif known:
                names = [r for r in robots if table.knows(*r)]
            else:
                names = list(robots)
            answers: RobotAnswers = []
            for fleet, robot in names:
                if not wanted(fleet, robot):
                    continue
                answer: Answer = (
                    table.state(fleet, robot) if state_wanted else table.area_graph(fleet, robot)
                )
                answers.append((fleet, robot, answer))
            return names, answers

        if known:  # each lane has a table; a stored robot is read once, from the store
            shards = [lane for shard in shards for lane in shard.lanes]
        futures: list[Future[tuple[list[tuple[str, str]], RobotAnswers]]] = [
            shard.read(read) for shard in shards
        ]
        names: list[tuple[str, str]] = []
        answers: RobotAnswers = []
        for shard, future in zip(shards, futures, strict=True):
            try:
                shard_names, shard_answers = future.result(timeout=_READ_WAIT_S)
            except FutureTimeout:
                log.warning(
                    "shard %d did not answer a query within %.0f s", shard.index, _READ_WAIT_S
                )
                continue
            names += shard_names
            answers += shard_answers
        return names, answers

    def _wanted(self, query: zenoh.Query, kind: str) -> Callable[[str, str], bool]:
        """Which robots a query is answered for: owned here (invariant 3), and its key named."""
        epoch_for = self._ownership.epoch_for
        selector = query.key_expr
        if kind == "submaps":
            return lambda fleet, robot: epoch_for(fleet, robot) is not None
        key_of = keys.areas if kind == "areas" else keys.state
        return lambda fleet, robot: (
            epoch_for(fleet, robot) is not None
            and selector.intersects(zenoh.KeyExpr(key_of(fleet, robot)))
        )

    def _reply(self, query: zenoh.Query, kind: str, answers: RobotAnswers) -> None:
        for fleet, robot, answer in answers:
            if answer is None:
                continue
            if kind == "submaps":
                assert isinstance(answer, SessionState)
                self._reply_submaps(query, fleet, robot, answer)
            elif isinstance(answer, AreaGraph):
                payload, cut = fit_area_graph(answer, self._reply_limits)
                self._note_cut("areas", fleet, robot, cut, "areas visited longest ago cut")
                enc = zenoh.Encoding(encoding(AreaGraph))
                query.reply(keys.areas(fleet, robot), payload, encoding=enc)
            else:
                payload, cut = fit_state(answer, self._reply_limits)
                self._note_cut("state", fleet, robot, cut, "oldest closed submaps left out")
                enc = zenoh.Encoding(encoding(SessionState))
                query.reply(keys.state(fleet, robot), payload, encoding=enc)

    def _reply_submaps(
        self, query: zenoh.Query, fleet: str, robot: str, state: SessionState
    ) -> None:
        candidates = [(state.current_submap, state.open)]
        candidates += [(closed, False) for closed in state.closed_submaps]
        for summary, is_open in candidates:
            key = keys.submap(fleet, robot, summary.id)
            if query.key_expr.intersects(zenoh.KeyExpr(key)):
                message = Submap(
                    fleet=fleet, robot=robot, session=state.session, summary=summary, open=is_open
                )
                query.reply(key, encode(message), encoding=zenoh.Encoding(encoding(Submap)))

    def _stored_robots(
        self, selector: zenoh.KeyExpr, answered: set[tuple[str, str]]
    ) -> list[tuple[str, str]]:
        """Robots of owned partitions the query names that only the store knows."""
        store = self._replication.store
        if not store.durable:
            return []

        def asked(fleet: str, robot: str) -> bool:
            return (
                (fleet, robot) not in answered
                and self._ownership.epoch_for(fleet, robot) is not None
                and selector.intersects(zenoh.KeyExpr(f"{keys.KEY_PREFIX}/{fleet}/{robot}/**"))
            )

        # The fleet and robot the selector names, if it names them without a wildcard: the
        # store then reads only their rows (robots poll their own state while they close).
        fleet, robot = named_fleet_and_robot(str(selector))
        try:
            return store.robots_where(asked, fleet=fleet, robot=robot)
        except sqlite3.Error as exc:
            log.warning("state store unreadable for a query: %s", exc)
            return []

    def _note_cut(self, kind: str, fleet: str, robot: str, cut: int, what: str) -> None:
        """Count a reply cut to the wire limits; log it once per robot and kind."""
        if not cut:
            return
        self._metrics.replies_cut.labels(kind).inc()
        if len(self._cuts_logged) >= _CUTS_LOGGED:
            self._cuts_logged.clear()  # bounded; a robot logged again is no harm
        if (kind, fleet, robot) not in self._cuts_logged:
            self._cuts_logged.add((kind, fleet, robot))
            limit = self._reply_limits.max_payload_bytes
            log.warning(
                "%s/%s %s reply over the wire limits (%d bytes, %d per list): %d %s",
                fleet,
                robot,
                kind,
                limit,
                self._reply_limits.max_list_len,
                cut,
                what,
            )

    def _reply_health(self, query: zenoh.Query) -> None:
        shards = [lane for shard in self._shards for lane in shard.lanes]
        health = Health(
            instance=self._settings.instance,
            version=__version__,
            sessions=sum(shard.open_sessions for shard in shards),
            uptime_s=time.monotonic() - self._started_s,
            frames_applied=self._frames_applied(),
            partitions=sorted(self._ownership.owned()),
            standby=self._ownership.standby(),
            queue_depth=sum(shard.depth() for shard in shards),
            lag_s=max((shard.lag_s(time.monotonic()) for shard in shards), default=0.0),
        )
        query.reply(
            keys.health(self._settings.instance),
            encode(health),
            encoding=zenoh.Encoding(encoding(Health)),
        )

    def _index_of(self, fleet: str, robot: str) -> int:
        return shard_index(keys.frames(fleet, robot), len(self._shards))

    def _shard_of(self, fleet: str, robot: str) -> Shard:
        """The shard (worker) of a robot: always the same one."""
        return self._shards[self._index_of(fleet, robot)]


def named_fleet_and_robot(selector: str) -> tuple[str | None, str | None]:
    """The fleet and robot chunks of a query's selector when they hold no wildcard."""
    chunks = [*selector.removeprefix(f"{keys.KEY_PREFIX}/").split("/"), "", ""]

    def plain(chunk: str) -> str | None:
        return chunk if chunk and not {"*", "$"} & set(chunk) else None

    fleet = plain(chunks[0])
    return fleet, plain(chunks[1]) if fleet is not None else None

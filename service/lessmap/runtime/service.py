"""The partition service: Zenoh declarations, shards, queries, ownership, lifecycle.

Threads: Zenoh's own (callbacks: enqueue only), one worker per shard, one query server, the
ownership thread (liveliness changes, taking over and handing over partitions, storing the
checkpoints shipped by the owners this instance stands by for), a heartbeat (freeze detection
for the fence, ``ownership.py``), and the caller's (``Service.start``/``stop``; ``serve``
parks it on a stop event). Callbacks never call Zenoh or block; queries are answered from the
query thread under the shard's lock.

Partitions (``schemas/README.md`` section 2a): the instance subscribes to the frames of the
partitions it owns only. Taking a partition over: query every instance for the partition's
checkpoints (the newest of each robot goes to the local store), take an epoch, subscribe; a
robot's next frame resumes its session from the store and fetches what is missing from the
robot's cache (the same path as after a restart). Handing one over: apply what already
arrived for it (bounded), close the fence, unsubscribe, checkpoint and drop its sessions,
then announce the release (``keys.released``, with the epoch it had).

The hand-shake: an instance that starts while others run wins partitions they own until they
see its token. It listens for their releases and holds the frames of those partitions
(``Receiver.hold``) before it declares its token, then waits (``handover_release_s`` at most)
until each former owner has announced the release, and only then fetches the checkpoints:
they are the former owner's final records, sessions it closed at the last moment included.
The held frames follow as probes (applied where the checkpoint does not cover them). A
former owner that is gone is not waited for (its token went: nothing to hand over).
"""

from __future__ import annotations

import logging
import queue
import sqlite3
import threading
import time
from typing import TYPE_CHECKING

import msgpack
import zenoh
from prometheus_client import start_http_server

from lessmap import __version__
from lessmap.config.partitioning import area_params
from lessmap.config.settings import EMBEDDED_ENDPOINT
from lessmap.core.segmenter import Method
from lessmap.errors import ConfigError
from lessmap.runtime.budget import EdgeLedger, SessionAdmission
from lessmap.runtime.metrics import ServiceMetrics
from lessmap.runtime.outbox import Outbox
from lessmap.runtime.ownership import Change, Ownership
from lessmap.runtime.receiver import EVERY_PARTITION, Receiver, shard_index
from lessmap.runtime.replies import fit_area_graph, fit_state
from lessmap.runtime.sessions import SessionTable
from lessmap.runtime.shard import CATCHUP_DONE, PROBE, RECOVERED, Inbound, Shard
from lessmap.runtime.store import CheckpointStore, SessionRecord, StoreError
from lessmap.runtime.zenoh_config import service_config
from lessmap_schemas import keys
from lessmap_schemas.codec import encode, encoding
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import AreaGraph, Health, SessionState, Submap
from lessmap_schemas.partition import PARTITIONS, partition_of

if TYPE_CHECKING:
    from collections.abc import Sequence
    from wsgiref.simple_server import WSGIServer

    from lessmap.config.settings import ServiceSettings
    from lessmap.runtime.sessions import CatchupRequest

log = logging.getLogger(__name__)

_QUEUE_BYTES_PER_SHARD = 256 * 1024 * 1024
_QUIET_S = 0.3  # no sample for this long: the inbound path has settled
_HEARTBEAT_S = 0.1  # freeze detection (fence_after_s is far above it)
_LEAVE_CONFIRM_S = 0.25  # a token that went is checked again this much later
_CHECKPOINT_ENCODING = zenoh.Encoding("application/octet-stream")
_RELEASE_VERSION = 1  # of the service-internal release announcement (``keys.released``)
# A hand-over first lets the shards apply what already arrived for the partitions, this long
# at most: well below handover_release_s, so the joining owner still gets the release.
_DRAIN_BEFORE_HANDOVER_S = 1.0
_ROUTER_WAIT_S = 10.0  # after a freeze, how long a client waits for its router again
_CUTS_LOGGED = 10_000  # robots whose cut replies were logged (then the set starts again)


class Service:
    """One lessmap service instance on a Zenoh session."""

    def __init__(self, settings: ServiceSettings, zenoh_cfg: Sequence[str] = ()) -> None:
        self.settings = settings
        self.metrics = ServiceMetrics()
        # Replies are cut to what readers accept (``replies``): the service's own limits.
        self._reply_limits = settings.limits.wire_limits()
        self._cuts_logged: set[tuple[str, str, str]] = set()
        self._zenoh_cfg = tuple(zenoh_cfg)
        self._session: zenoh.Session | None = None
        self._outbox: Outbox | None = None
        self._shards: list[Shard] = []
        self._declared: list[zenoh.Subscriber[None] | zenoh.Queryable[None]] = []
        self._token: zenoh.LivelinessToken | None = None
        self._queries: queue.SimpleQueue[zenoh.Query | None] = queue.SimpleQueue()
        self._query_thread = threading.Thread(
            target=self._serve_queries, name="lessmap-queries", daemon=True
        )
        self._metrics_server: WSGIServer | None = None
        self.store = CheckpointStore(
            None if settings.memory_only else settings.resolved_state_dir(),
            retention_s=settings.state_retention_s,
            max_bytes=settings.state_max_bytes,
        )
        self._started_s = time.monotonic()
        self.metrics_port: int | None = None
        self.ownership = Ownership(settings.instance, freeze_s=settings.fence_after_s)
        self._frame_subs: dict[int, zenoh.Subscriber[zenoh.Handler[zenoh.Sample]]] = {}
        self._receiver: Receiver | None = None
        self._standby_subs: dict[int, zenoh.Subscriber[None]] = {}
        self._liveliness_sub: zenoh.Subscriber[None] | None = None
        # Release announcements of the former owners, while this instance waits for them
        # (start-up only): the subscriber's callback only enqueues.
        self._releases: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        # Liveliness changes, freezes and shipped checkpoints, for the ownership thread.
        self._control: queue.SimpleQueue[tuple[str, object] | None] = queue.SimpleQueue()
        self._control_thread = threading.Thread(
            target=self._run_control, name="lessmap-ownership", daemon=True
        )
        self._heartbeat_stop = threading.Event()
        self._heartbeat_thread = threading.Thread(
            target=self._run_heartbeat, name="lessmap-heartbeat", daemon=True
        )

    # -- lifecycle ---------------------------------------------------------------------------

    def start(self) -> None:
        """Open Zenoh, declare everything and start the workers.

        Raises:
            ConfigError: the Zenoh configuration is invalid, or Zenoh could not open (for
                example the port is taken).
        """
        s = self.settings
        try:
            self.store.open()
        except StoreError as exc:
            msg = str(exc)
            raise ConfigError(msg) from exc
        conf = service_config(s, self._zenoh_cfg)
        try:
            self._session = session = zenoh.open(conf)
        except zenoh.ZError as exc:
            where = EMBEDDED_ENDPOINT if s.embedded else ", ".join(s.listen) or "its endpoints"
            msg = f"Zenoh could not start on {where}: {exc}"
            raise ConfigError(msg) from exc
        per_shard_sessions = max(1, -(-s.max_sessions // s.workers))
        self._outbox = Outbox(
            session,
            self.metrics,
            instance=s.instance,
            transition_cache=s.transition_cache,
            max_publishers=s.max_sessions,
            error_rate_per_s=s.error_rate_per_s,
            error_burst=s.error_burst,
            epoch_for=self.ownership.epoch_for,
            release_memory=self.store.release_memory_soon,
            store=self.store,
        )
        params = s.partition_params()
        ledger = EdgeLedger(s.workers, s.max_edges_total)
        admission = SessionAdmission(s.new_sessions_per_s_per_fleet, s.new_sessions_burst)
        for index in range(s.workers):
            table = SessionTable(
                params,
                method=Method(s.method),
                area_params=area_params(s),
                omits_empty_frames=s.omits_empty_frames,
                max_sessions=per_shard_sessions,
                max_nodes=s.max_nodes_per_session,
                max_batch_frames=s.max_batch_frames,
                idle_timeout_s=s.session_idle_timeout_s,
                instance=s.instance,
                clock=time.perf_counter,
                store=self.store,
                checkpoint_every_frames=s.checkpoint_every_frames,
                checkpoint_interval_s=s.checkpoint_interval_s,
                # Catch-up with a store only: memory-only keeps today's immediate SEQ_GAP.
                catchup_max_frames=0 if self.store.path is None else s.catchup_max_frames,
                catchup_wait_s=s.catchup_wait_s,
                max_pairs_per_frame=s.max_pairs_per_frame,
                max_edges=s.max_edges_per_session,
                ledger=ledger,
                ledger_slot=index,
                admission=admission,
                epoch_of=self.ownership.last_epoch,
            )
            self._shards.append(
                Shard(
                    index,
                    table,
                    self._outbox,
                    limits=s.limits.wire_limits(),
                    queue_depth=s.queue_depth,
                    queue_bytes=_QUEUE_BYTES_PER_SHARD,
                    linger_s=s.batch_linger_ms / 1000.0,
                    request_catchup=self._request_catchup,
                    quantum=s.fair_quantum,
                    coalesce_after_s=s.coalesce_after_ms / 1000.0,
                    owns=self.ownership.owns,
                )
            )
        self._receiver = Receiver(
            self._shards,
            self.metrics,
            max_payload_bytes=s.limits.max_payload_bytes,
            queue_depth=s.queue_depth,
            owned=lambda p: self.ownership.epoch_of(p) is not None,
        )
        for shard in self._shards:
            shard.start()
        self._receiver.start()
        self._query_thread.start()
        # Metrics before any declaration: frames can arrive as soon as a partition is taken.
        if s.metrics_port is not None:
            server, _thread = start_http_server(
                s.metrics_port, addr=s.metrics_addr, registry=self.metrics.registry
            )
            self._metrics_server = server
            self.metrics_port = server.server_port
        any_robot = f"{keys.KEY_PREFIX}/*/*"
        self._declared.append(session.declare_queryable(f"{any_robot}/state", self._queries.put))
        self._declared.append(session.declare_queryable(f"{any_robot}/areas", self._queries.put))
        self._declared.append(
            session.declare_queryable(f"{any_robot}/submaps/*", self._queries.put)
        )
        self._declared.append(session.declare_queryable(keys.health(s.instance), self._queries.put))
        # Checkpoints: every instance answers for those it holds (a new owner asks).
        self._declared.append(session.declare_queryable(keys.checkpoints(), self._queries.put))
        # Frames: one plain subscriber per owned partition (``_take``). Catch-up is an
        # explicit query of the robot's publication cache (``_request_catchup``), sent by the
        # worker when its session table holds frames beyond a gap. An AdvancedSubscriber with
        # history was tried and is not used: the robots' publishers have no sample miss
        # detection (no sequence numbers), so it orders each publisher's samples by
        # timestamp and dropped history older than a live sample that overtook it (frame 0
        # of a new session, then others), and with ``detect_late_publishers`` on a wildcard
        # every new robot costs a history query of its whole cache. The query is asked only
        # on a gap, for one robot, and the table puts what comes back in seq order itself.
        self.store.on_written = self._ship
        # Alone, take every partition first (frames subscriptions, checkpoints, cache
        # probes), then declare the token: declarations reach every client in order, so one
        # that sees the token already routes its frames here. With others running, the
        # partitions this instance wins are theirs until they see its token: hold their
        # frames, declare the token, then take them as the former owners release them
        # (module doc). The live tokens are asked before the liveliness subscriber is
        # declared: with a history subscriber declared first, zenoh 1.x answered the get
        # with the local token only. The subscriber follows at once, before the take: an
        # instance that leaves while this one waits for releases must not go unseen. Its
        # history repeats what the get saw; joins are idempotent. Its changes queue up for
        # the ownership thread, which starts once this instance has taken its partitions.
        live = self._live_instances()
        log.info("live instances: %s", ", ".join(sorted(set(live))))
        self._liveliness_sub = session.liveliness().declare_subscriber(
            keys.instances(), self._on_liveliness, history=True
        )
        self.ownership.start_clock()
        self._heartbeat_thread.start()
        change = self.ownership.set_live(live, arriving=True)
        if change.handed_by:
            self._join(change)
        else:
            self._apply(change)
            self._declare_token()
        self._control_thread.start()
        log.info(
            "lessmap %s serving as %s (%s, method %s, %d shard(s), profile %s, %d of %d "
            "partitions)%s",
            __version__,
            s.instance,
            "embedded router on tcp/127.0.0.1:7447" if s.embedded else "joined Zenoh network",
            s.method,
            s.workers,
            s.profile,
            len(self.ownership.owned()),
            PARTITIONS,
            f", metrics on http://{s.metrics_addr}:{self.metrics_port}/metrics"
            if self.metrics_port is not None
            else "",
        )
        if self.store.path is None:
            log.info("sessions live in memory only (--memory-only): a restart loses them")
        else:
            log.info("session checkpoints in %s", self.store.path)
            self._check_catchup_budget()

    def _declare_token(self) -> None:
        assert self._session is not None
        token = keys.instance_token(self.settings.instance)
        self._token = self._session.liveliness().declare_token(token)

    def _join(self, change: Change, *, declare_token: bool = True) -> None:
        """Take partitions from the live instances that hold them (start-up, module doc).

        After a freeze the token is already declared: the others see it again as the
        session reconnects.
        """
        session = self._session
        assert session is not None
        while not self._releases.empty():  # announcements of an earlier join, already used
            self._releases.get_nowait()
        releases = session.declare_subscriber(keys.released(), self._on_released)
        try:
            self._hold_frames(sorted(change.handed_by))
            if declare_token:
                self._declare_token()  # the former owners hand over when they see it
            self._apply(change)
        finally:
            releases.undeclare()

    def _check_catchup_budget(self) -> None:
        """Warn when a crash can lose frames that the robots' caches would have held.

        After a crash a session resumes at its last checkpoint, so a catch-up must fetch
        the frames since that checkpoint (at most ``checkpoint_every_frames``) plus those
        sent while no instance ran. The rule (README, "Behaviour worth knowing"):
        ``checkpoint_every_frames + rate x downtime <= min(robot cache, catchup_max_frames)``.
        """
        s = self.settings
        budget = s.catchup_max_frames - s.checkpoint_every_frames
        if budget <= 0:
            log.warning(
                "checkpoint_every_frames %d >= catchup_max_frames %d: after a crash the "
                "frames between the last checkpoint and the oldest one a catch-up asks for "
                "are lost; lower checkpoint_every_frames or raise catchup_max_frames",
                s.checkpoint_every_frames,
                s.catchup_max_frames,
            )
        else:
            log.info(
                "catch-up: up to %d frames per robot; %d of them are left for the downtime "
                "after a crash (e.g. %.0f s at 10 frames/s), if the robots' caches hold "
                "that many",
                s.catchup_max_frames,
                budget,
                budget / 10.0,
            )

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop taking frames, finish the queued ones, publish final states, close Zenoh."""
        log.info("stopping %s", self.settings.instance)
        self._let_inbound_settle(min(timeout_s / 2, self.settings.shutdown_grace_s))
        self._heartbeat_stop.set()
        self._control.put(None)
        if self._control_thread.is_alive():
            self._control_thread.join(max(1.0, self.settings.handover_fetch_s + 1.0))
        if self._liveliness_sub is not None:
            self._liveliness_sub.undeclare()
            self._liveliness_sub = None
        for frames_sub in self._frame_subs.values():
            frames_sub.undeclare()
        self._frame_subs.clear()
        if self._receiver is not None:
            self._receiver.stop()  # the last sweep takes what the channels still hold
        for standby_sub in self._standby_subs.values():
            standby_sub.undeclare()
        self._standby_subs.clear()
        for declared in reversed(self._declared):
            declared.undeclare()  # type: ignore[no-untyped-call]
        self._declared.clear()
        deadline = time.monotonic() + timeout_s
        for shard in self._shards:
            shard.stop(max(0.1, deadline - time.monotonic()))
        if self._outbox is not None:
            now = time.monotonic()
            for shard in self._shards:
                with shard.lock:
                    outcome = shard.table.close_all("shutdown")
                    self._outbox.publish(outcome, now)
        self.store.close()
        self._queries.put(None)
        if self._query_thread.is_alive():
            self._query_thread.join(1.0)
        if self._token is not None:
            self._token.undeclare()
        if self._outbox is not None:
            self._outbox.close()
        if self._metrics_server is not None:
            self._metrics_server.shutdown()
            self._metrics_server.server_close()
        if self._session is not None:
            self._session.close()
        log.info("stopped %s", self.settings.instance)

    def _let_inbound_settle(self, grace_s: float) -> None:
        """Keep listening until samples stop arriving (or ``grace_s`` passes).

        Frames a robot sent before the stop may still be on their way through Zenoh; taking
        them in before undeclaring the subscriber loses none that already arrived.
        """
        receiver = self._receiver
        if receiver is None:
            return
        deadline = time.monotonic() + grace_s
        # Sweep here rather than wait for the receiver's tick (up to 50 ms when idle): a
        # sample already in a channel has arrived, and counts as arrived now.
        receiver.sweep()
        while time.monotonic() < deadline and time.monotonic() - receiver.last_sample_s < _QUIET_S:
            time.sleep(0.02)
            receiver.sweep()

    # -- receive path (``receiver.py``; catch-up replies: callbacks that enqueue only) ----

    def _request_catchup(self, shard: Shard, request: CatchupRequest) -> None:
        """Ask a robot's publication cache for its newest frames (worker thread, no wait).

        The query goes to the cache queryables of the robot's frames key (``@adv/**`` below
        it, where AdvancedPublishers answer) with callbacks: replies and the query's end are
        only enqueued on the shard, like live samples, so neither the worker nor a Zenoh
        thread waits. Consolidation is off (every cached sample has the same key) and
        replies keyed as the frames are accepted (they do not match the ``@adv`` selector).
        """
        session = self._session
        key = keys.frames(request.fleet, request.robot)
        max_payload = self.settings.limits.max_payload_bytes
        done = Inbound(0.0, key, request.session.encode(), CATCHUP_DONE)
        if session is None or not self.ownership.owns(request.fleet, request.robot):
            shard.offer(done)
            return

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh's thread: enqueue only
            sample = reply.ok
            if sample is None or str(sample.key_expr) != key:
                return  # an error reply, or a queryable answering for another key
            if len(sample.payload) > max_payload:
                return
            shard.offer(Inbound(time.monotonic(), key, sample.payload.to_bytes(), RECOVERED))

        def on_end() -> None:  # the query is over: every reply was delivered, or timed out
            shard.offer(Inbound(time.monotonic(), key, done.payload, CATCHUP_DONE))

        log.debug("catch-up of %s after seq %d", key, request.after_seq)
        try:
            session.get(
                f"{key}/@adv/**?_max={request.max_frames}",
                zenoh.handlers.Callback(on_reply, on_end),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                accept_replies=zenoh.ReplyKeyExpr.ANY,
                timeout=self.settings.catchup_wait_s,
            )
        except zenoh.ZError as exc:  # a closing session: the hold is released at once
            log.warning("catch-up query of %s failed: %s", key, exc)
            shard.offer(done)

    def _shard_of(self, key: str) -> Shard:
        """Return the shard (worker) of a robot's key: always the same one for a robot."""
        return self._shards[shard_index(key, len(self._shards))]

    # -- queries -----------------------------------------------------------------------------

    def _serve_queries(self) -> None:
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
            self._reply_checkpoints(query)
            return
        is_submap = "/submaps/" in text
        is_areas = text.endswith("/areas")
        answered: set[tuple[str, str]] = set()
        named_fleet, named_robot = _named_fleet_and_robot(text)
        if named_fleet is not None and named_robot is not None:
            # One robot named (robots poll their own state while they close, apps ask for
            # one robot): only its shard can hold it, so only it is checked, not every
            # robot of every shard against the selector.
            shard = self._shard_of(keys.frames(named_fleet, named_robot))
            with shard.lock:
                if shard.table.knows(named_fleet, named_robot):
                    self._reply_robot(query, shard, named_fleet, named_robot, is_submap, is_areas)
                    return
        else:
            for shard in self._shards:
                with shard.lock:
                    robots = shard.table.robots()
                    answered.update(robots)
                    for fleet, robot in robots:
                        self._reply_robot(query, shard, fleet, robot, is_submap, is_areas)
        # Robots known only from the store (closed before a restart, evicted, or whose
        # records came with a partition taken over): the table answers from their record.
        for fleet, robot in self._stored_robots(selector, answered):
            shard = self._shard_of(keys.frames(fleet, robot))
            with shard.lock:
                self._reply_robot(query, shard, fleet, robot, is_submap, is_areas)

    def _stored_robots(
        self, selector: zenoh.KeyExpr, answered: set[tuple[str, str]]
    ) -> list[tuple[str, str]]:
        """Robots of owned partitions the query names that only the store knows."""
        if not self.store.durable:
            return []

        def asked(fleet: str, robot: str) -> bool:
            return (
                (fleet, robot) not in answered
                and self.ownership.epoch_for(fleet, robot) is not None
                and selector.intersects(zenoh.KeyExpr(f"{keys.KEY_PREFIX}/{fleet}/{robot}/**"))
            )

        # The fleet and robot the selector names, if it names them without a wildcard: the
        # store then reads only their rows (robots poll their own state while they close).
        fleet, robot = _named_fleet_and_robot(str(selector))
        try:
            return self.store.robots_where(asked, fleet=fleet, robot=robot)
        except sqlite3.Error as exc:
            log.warning("state store unreadable for a query: %s", exc)
            return []

    def _reply_robot(
        self,
        query: zenoh.Query,
        shard: Shard,
        fleet: str,
        robot: str,
        is_submap: bool,
        is_areas: bool,
    ) -> None:
        """Answer a state, areas or submaps query for one robot (its shard's lock held)."""
        if self.ownership.epoch_for(fleet, robot) is None:
            return  # handed over (or frozen): the owner answers
        if is_submap:
            self._reply_submaps(query, shard, fleet, robot)
            return
        if is_areas:
            self._reply_areas(query, shard, fleet, robot)
            return
        key = keys.state(fleet, robot)
        if not query.key_expr.intersects(zenoh.KeyExpr(key)):
            return
        state = shard.table.state(fleet, robot)
        if state is not None:
            payload, cut = fit_state(state, self._reply_limits)
            self._note_cut("state", fleet, robot, cut, "oldest closed submaps left out")
            query.reply(key, payload, encoding=zenoh.Encoding(encoding(SessionState)))

    def _reply_areas(self, query: zenoh.Query, shard: Shard, fleet: str, robot: str) -> None:
        key = keys.areas(fleet, robot)
        if not query.key_expr.intersects(zenoh.KeyExpr(key)):
            return
        graph = shard.table.area_graph(fleet, robot)
        if graph is not None:
            payload, cut = fit_area_graph(graph, self._reply_limits)
            self._note_cut("areas", fleet, robot, cut, "areas visited longest ago cut")
            query.reply(key, payload, encoding=zenoh.Encoding(encoding(AreaGraph)))

    def _note_cut(self, kind: str, fleet: str, robot: str, cut: int, what: str) -> None:
        """Count a reply cut to the wire limits; log it once per robot and kind."""
        if not cut:
            return
        self.metrics.replies_cut.labels(kind).inc()
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

    def _reply_submaps(self, query: zenoh.Query, shard: Shard, fleet: str, robot: str) -> None:
        state = shard.table.state(fleet, robot)
        if state is None:
            return
        candidates = [(state.current_submap, state.open)]
        candidates += [(closed, False) for closed in state.closed_submaps]
        for summary, is_open in candidates:
            key = keys.submap(fleet, robot, summary.id)
            if query.key_expr.intersects(zenoh.KeyExpr(key)):
                message = Submap(
                    fleet=fleet, robot=robot, session=state.session, summary=summary, open=is_open
                )
                query.reply(key, encode(message), encoding=zenoh.Encoding(encoding(Submap)))

    def _reply_health(self, query: zenoh.Query) -> None:
        health = Health(
            instance=self.settings.instance,
            version=__version__,
            sessions=sum(len(shard.table) for shard in self._shards),
            uptime_s=time.monotonic() - self._started_s,
            frames_applied=self._outbox.frames_applied if self._outbox is not None else 0,
            partitions=sorted(self.ownership.owned()),
            standby=self.ownership.standby(),
            queue_depth=sum(shard.depth() for shard in self._shards),
            lag_s=max((shard.lag_s(time.monotonic()) for shard in self._shards), default=0.0),
        )
        query.reply(
            keys.health(self.settings.instance),
            encode(health),
            encoding=zenoh.Encoding(encoding(Health)),
        )

    def _reply_checkpoints(self, query: zenoh.Query) -> None:
        """Answer with the checkpoints this instance holds that the selector asks for."""
        selector = query.key_expr
        chunks = str(selector).split("/")
        wanted = int(chunks[4]) if len(chunks) > 4 and chunks[4].isdigit() else None

        def asked(fleet: str, robot: str) -> bool:
            p = partition_of(fleet, robot)
            if wanted is not None and p != wanted:
                return False
            return selector.intersects(zenoh.KeyExpr(keys.checkpoints(p, fleet, robot)))

        for record in self.store.records_where(asked):
            key = keys.checkpoints(partition_of(record.fleet, record.robot), *record.key)
            query.reply(key, record.to_bytes(), encoding=_CHECKPOINT_ENCODING)

    # -- ownership ---------------------------------------------------------------------------

    def _on_liveliness(self, sample: zenoh.Sample) -> None:  # Zenoh's thread: enqueue only
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        kind = "join" if sample.kind == zenoh.SampleKind.PUT else "leave"
        self._control.put((kind, name))

    def _on_released(self, sample: zenoh.Sample) -> None:  # Zenoh's thread: enqueue only
        self._releases.put((str(sample.key_expr), sample.payload.to_bytes()))

    def _live_instances(self) -> list[str]:
        """Ask the network for the live instance tokens (this one included)."""
        assert self._session is not None
        names = [self.settings.instance]
        try:
            replies = self._session.liveliness().get(keys.instances(), timeout=1.0)
            for reply in replies:
                if reply.ok is not None:
                    names.append(str(reply.ok.key_expr).rsplit("/", 1)[-1])
        except zenoh.ZError as exc:
            log.warning("could not list the live instances: %s", exc)
        return names

    def _run_heartbeat(self) -> None:
        while not self._heartbeat_stop.wait(_HEARTBEAT_S):
            if self.ownership.tick():
                self._control.put(("frozen", None))

    def _run_control(self) -> None:
        while True:
            item = self._control.get()
            if item is None:
                return
            kind, value = item
            try:
                if kind == "join":
                    self._apply(self.ownership.join(str(value)))
                elif kind == "leave":
                    if self._confirm_leave(str(value)):
                        self._apply(self.ownership.leave(str(value)))
                elif kind == "checkpoint":
                    self._take_replica(*value)  # type: ignore[misc]
                elif kind == "frozen":
                    self._after_freeze()
            except Exception:
                # A bug must not stop ownership changes: log it, keep going.
                log.exception("ownership change %s %s failed", kind, value)

    def _confirm_leave(self, name: str) -> bool:
        """True when an instance whose token went is still gone a moment later.

        Taking partitions over is the risky direction (two owners for a moment), so a leave
        is checked: a client that loses its router sees every other token go and come back
        when it reconnects (after a freeze, a network blip). A client without a router sees
        nothing reliable and takes nothing.
        """
        time.sleep(_LEAVE_CONFIRM_S)
        session = self._session
        if session is None:
            return False
        if self._without_router(session):
            log.info("token of %s went while this instance has no router; waiting", name)
            return False
        if name in self._live_instances():
            log.info("token of %s went and came back; nothing moves", name)
            return False
        return True

    def _after_freeze(self) -> None:
        """The process stalled past the fence: drop everything, then take back what is ours."""
        log.warning(
            "%s stalled for more than %.1f s: every partition dropped (another instance may "
            "have taken them over); rejoining",
            self.settings.instance,
            self.settings.fence_after_s,
        )
        self._hand_over(sorted(self.ownership.owned()))
        for p in list(self._standby_subs):
            self._standby_subs.pop(p).undeclare()
        self._wait_for_router()
        # Back as a joiner comes: the partitions this instance wins again were taken over
        # while it was frozen, so their owners now hand them over (their release, with
        # their final checkpoints) before it fetches; their frames are held meanwhile. Taken
        # at once, they resumed from this instance's own old checkpoints, and a session
        # whose frames the robot's cache no longer held went on past a gap, publishing
        # transitions unlike the owner's (seen in one full test run: SEQ_GAP of 264 frames).
        change = self.ownership.set_live(self._live_instances(), arriving=True)
        if change.handed_by:
            self._join(change, declare_token=False)
        else:
            self._apply(change)

    def _without_router(self, session: zenoh.Session) -> bool:
        """True for a client connected to no router: it sees no other instance's token."""
        return self.settings.mode == "client" and not list(session.info.routers_zid())

    def _wait_for_router(self) -> None:
        """After a freeze, wait (bounded) until a client is connected to a router again.

        A client whose router dropped it during the freeze sees no other token until it has
        reconnected: asked for the live instances before that, it would take every partition.
        """
        session = self._session
        if session is None:
            return
        deadline = time.monotonic() + _ROUTER_WAIT_S
        while self._without_router(session):
            if time.monotonic() > deadline:
                log.warning(
                    "no router %.0f s after the freeze: taking partitions on what this "
                    "instance sees",
                    _ROUTER_WAIT_S,
                )
                return
            time.sleep(0.1)

    def _apply(self, change: Change) -> None:
        """Carry out a change of ownership (ownership thread, or ``start``)."""
        if not change:
            return
        self._hand_over(change.lost)
        session = self._session
        assert session is not None
        for p in change.standby_lost:
            self.ownership.set_standby(p, on=False)
            sub = self._standby_subs.pop(p, None)
            if sub is not None:
                sub.undeclare()
        for p in change.standby_gained:
            self.ownership.set_standby(p, on=True)
            if self.store.path is not None and p not in self._standby_subs:
                self._standby_subs[p] = session.declare_subscriber(
                    keys.checkpoints(p), self._on_replica
                )
        if change.gained:
            self._take(change.gained, change.handed_by)
        self.metrics.partitions_owned.set(len(self.ownership.owned()))

    def _hand_over(self, partitions: Sequence[int]) -> None:
        """Apply what arrived, close the fence, unsubscribe, checkpoint, drop, announce."""
        if not partitions:
            return
        leaving = set(partitions)
        self._apply_arrived(leaving)
        epochs = self.ownership.owned()  # before the release: what the announcement names
        for p in partitions:
            self.ownership.release(p)
            sub = self._frame_subs.pop(p, None)
            if sub is not None:
                sub.undeclare()
        if self._receiver is not None:
            self._receiver.watch(self._frame_subs)
        now = time.monotonic()
        dropped = 0
        for shard in self._shards:
            with shard.lock:  # after any turn that decided before the fence closed
                out = shard.table.hand_over(
                    lambda fleet, robot: partition_of(fleet, robot) in leaving, now
                )
                if self._outbox is not None:
                    # Counters and checkpoints only (the fence is closed): not those of a
                    # session with a fenced transition (the next owner decides it anew).
                    self._outbox.publish(out, now)
            dropped += out.evicted
        # The sessions' final records are in the store now (pending ones included, which the
        # checkpoint queries read): a new owner waiting for this fetches them next.
        self._announce_released(partitions, epochs)
        self.metrics.partition_moves.labels(direction="out").inc(len(partitions))
        log.info(
            "handed over %d partition(s) (%d session(s) checkpointed): %s",
            len(partitions),
            dropped,
            _ranges(partitions),
        )

    def _announce_released(self, partitions: Sequence[int], epochs: dict[int, int]) -> None:
        """Say that these partitions were handed over (a joining owner waits for it)."""
        session = self._session
        if session is None or len(self.ownership.live) < 2:
            return  # alone: nobody takes them (a freeze dropped them, say)
        for p in partitions:
            epoch = epochs.get(p)
            if epoch is None:
                continue  # not held under an epoch (fenced by a freeze): nothing was decided
            payload = msgpack.packb({"released": _RELEASE_VERSION, "epoch": epoch})
            try:
                key = keys.released(p, self.settings.instance)
                session.put(key, payload, encoding=_CHECKPOINT_ENCODING)
            except zenoh.ZError as exc:
                log.warning("could not announce the release of partition %d: %s", p, exc)

    def _await_releases(self, handed_by: dict[int, str]) -> None:
        """Wait until each partition's former owner announced its release (bounded).

        On time out the take goes on as without a hand-shake (checkpoints as they are, the
        robots' caches for the rest): a former owner that does not answer must not keep the
        partitions unserved.
        """
        waiting = dict(handed_by)
        wait_s = self.settings.handover_release_s
        deadline = time.monotonic() + wait_s
        while waiting:
            try:
                key, payload = self._releases.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            release = _read_release(key, payload)
            if release is not None and waiting.get(release[0]) == release[1]:
                del waiting[release[0]]
                self.ownership.saw_epoch(release[0], release[2])
        if waiting:
            self.metrics.handover_release_timeouts.inc(len(waiting))
            log.warning(
                "%d partition(s) taken without a release from %s within %.1f s: %s",
                len(waiting),
                ", ".join(sorted(set(waiting.values()))),
                wait_s,
                _ranges(sorted(waiting)),
            )

    def _hold_frames(self, partitions: Sequence[int]) -> None:
        """Subscribe to the partitions' frames now and keep them aside until taken."""
        if self._receiver is not None:
            self._receiver.hold(partitions)
            self._subscribe_frames(partitions)

    def _subscribe_frames(self, partitions: Sequence[int]) -> None:
        session = self._session
        assert session is not None
        assert self._receiver is not None
        subs = self._frame_subs
        if self.settings.frames_subscription == "all":
            # One subscription for good; the receiver keeps the owned partitions' frames.
            if EVERY_PARTITION not in subs:
                subs[EVERY_PARTITION] = session.declare_subscriber(
                    keys.frames_of_every_partition(), self._receiver.channel()
                )
        else:
            for p in partitions:
                if p not in subs:
                    subs[p] = session.declare_subscriber(
                        keys.frames_of_partition(p), self._receiver.channel()
                    )
        self._receiver.watch(subs)

    def _apply_arrived(self, leaving: set[int]) -> None:
        """Let the shards apply what arrived for partitions about to be handed over.

        A frame or end that reached this instance before the new owner subscribed reached
        nobody else (Zenoh forwarded it here before the new owner's token, which came after
        its subscription): dropped as foreign after the release, it would be lost but for
        the robot's cache, and a ``SessionEnd`` is never in a cache. Bounded: under overload
        what is left goes to the new owner's probe and catch-up, as before.
        """
        receiver = self._receiver
        if receiver is None:
            return
        receiver.sweep()  # what the channels hold now, into the shards

        def of_leaving(key: str) -> bool:
            chunk = key[key.rfind("/") + 1 :]
            return chunk.isdecimal() and int(chunk) in leaving

        deadline = time.monotonic() + _DRAIN_BEFORE_HANDOVER_S
        while any(shard.holds_any(of_leaving) for shard in self._shards):
            if time.monotonic() >= deadline:
                log.info("handing over with frames still queued: the new owner's probe follows")
                return
            time.sleep(0.005)

    def _take(self, partitions: Sequence[int], handed_by: dict[int, str] | None = None) -> None:
        """Fetch the partitions' newest checkpoints, take epochs, subscribe to their frames.

        ``handed_by``: partitions a live former owner hands over; their checkpoints are
        fetched once it announced the release (``_await_releases``).
        """
        started = time.monotonic()
        if handed_by:
            self._await_releases({p: handed_by[p] for p in partitions if p in handed_by})
        fetched = self._fetch_checkpoints(partitions)
        held = 0
        if self._receiver is not None:
            held = self._receiver.admit(partitions, self.ownership.acquire)
            self._subscribe_frames(partitions)
        else:
            for p in partitions:
                self.ownership.acquire(p)
        for p in partitions:
            self._probe_caches(p)
        self.metrics.partition_moves.labels(direction="in").inc(len(partitions))
        log.info(
            "took %d partition(s) in %.0f ms (%d checkpoint(s) from other instances, %d "
            "frame(s) held meanwhile): %s",
            len(partitions),
            (time.monotonic() - started) * 1000.0,
            fetched,
            held,
            _ranges(partitions),
        )

    def _probe_caches(self, partition: int) -> None:
        """Ask the robots' caches of a partition just taken for their newest frame each.

        A robot that sent frames while no instance was subscribed to its partition (before
        the first owner subscribed, or between an owner's death and the take-over) and then
        fell silent would otherwise wait for its next frame. Each cache answers with its
        newest frame (``_max=1``), which the shard applies like a live one only if the table
        does not know it (``SessionTable.is_news``): a session ahead of its checkpoint, or
        unknown, then resumes and catches up as after a gap; a frame already seen is dropped
        uncounted (it was counted when it arrived). Callbacks only enqueue, on the receiver:
        its next sweep hands a reply on behind the live frames already received, which the
        robot put before its cache answered (``Receiver.probe``).
        """
        session = self._session
        if session is None or self.store.path is None:
            return  # memory-only: no catch-up (gaps are reported at once)
        suffix = f"/frames/{partition}"
        max_payload = self.settings.limits.max_payload_bytes
        receiver = self._receiver

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh's thread: enqueue only
            sample = reply.ok
            if sample is None or len(sample.payload) > max_payload:
                return
            key = str(sample.key_expr)
            if key.endswith(suffix) and "@" not in key:
                item = Inbound(time.monotonic(), key, sample.payload.to_bytes(), PROBE)
                if receiver is not None:
                    receiver.probe(item)  # behind the live frames already received
                else:
                    self._shard_of(key).offer(item)

        try:
            session.get(
                f"{keys.frames_of_partition(partition)}/@adv/**?_max=1",
                zenoh.handlers.Callback(on_reply, lambda: None),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                accept_replies=zenoh.ReplyKeyExpr.ANY,
                timeout=self.settings.catchup_wait_s,
            )
        except zenoh.ZError as exc:
            log.warning("probe of the robots' caches of partition %d failed: %s", partition, exc)

    def _fetch_checkpoints(self, partitions: Sequence[int]) -> int:
        """Ask every instance for the partitions' checkpoints; keep the newest per robot."""
        session = self._session
        if session is None or self.store.path is None or len(self.ownership.live) < 2:
            return 0
        replies: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        ended = threading.Semaphore(0)

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh's thread: enqueue only
            if reply.ok is not None:
                replies.put((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))

        def on_end() -> None:
            ended.release()

        wait_s = self.settings.handover_fetch_s
        asked = 0
        for p in partitions:
            try:
                session.get(
                    keys.checkpoints(p),
                    zenoh.handlers.Callback(on_reply, on_end),
                    target=zenoh.QueryTarget.ALL,
                    consolidation=zenoh.ConsolidationMode.NONE,
                    timeout=wait_s,
                )
                asked += 1
            except zenoh.ZError as exc:
                log.warning("checkpoint query of partition %d failed: %s", p, exc)
        deadline = time.monotonic() + wait_s + 0.5
        for _ in range(asked):
            if not ended.acquire(timeout=max(0.0, deadline - time.monotonic())):
                log.warning("checkpoint queries unanswered after %.1f s; going on", wait_s)
                break
        taken = 0
        while not replies.empty():
            key, payload = replies.get()
            if self._store_replica(key, payload):
                taken += 1
        return taken

    def _on_replica(self, sample: zenoh.Sample) -> None:  # Zenoh's thread: enqueue only
        self._control.put(("checkpoint", (str(sample.key_expr), sample.payload.to_bytes())))

    def _take_replica(self, key: str, payload: bytes) -> None:
        p = key.split("/")[4] if key.count("/") >= 4 else ""
        if p.isdigit() and self.ownership.epoch_of(int(p)) is not None:
            return  # this instance owns it: a deposed owner's late checkpoint
        self._store_replica(key, payload)

    def _store_replica(self, key: str, payload: bytes) -> bool:
        """Keep a checkpoint shipped or returned by another instance, if it is newer."""
        try:
            partition, fleet, robot = keys.parse_checkpoint_key(key)
            record = SessionRecord.from_bytes(payload)
        except (WireError, ValueError) as exc:
            log.warning("ignored a checkpoint on %s: %s", key[:200], exc)
            return False
        if record.key != (fleet, robot):
            log.warning("ignored a checkpoint on %s: it is %s/%s's", key[:200], *record.key)
            return False
        self.ownership.saw_epoch(partition, record.epoch)
        if self.store.offer(record):
            self.metrics.checkpoints_received.inc()
            return True
        return False

    def _ship(self, records: list[SessionRecord]) -> None:
        """Put the checkpoints just written for the standby (the store's writer thread)."""
        session = self._session
        if session is None or len(self.ownership.live) < 2:
            return  # alone: nobody to ship to
        for record in records:
            p = partition_of(record.fleet, record.robot)
            if self.ownership.epoch_of(p) is None:
                continue  # not ours (a replica, or handed over)
            try:
                session.put(
                    keys.checkpoints(p, record.fleet, record.robot),
                    record.to_bytes(),
                    encoding=_CHECKPOINT_ENCODING,
                )
                self.metrics.checkpoints_shipped.inc()
            except zenoh.ZError as exc:
                log.warning("could not ship the checkpoint of %s/%s: %s", *record.key, exc)


def _read_release(key: str, payload: bytes) -> tuple[int, str, int] | None:
    """(partition, instance, epoch) of a release announcement, None if it is not one."""
    try:
        partition, instance = keys.parse_released_key(key)
        obj = msgpack.unpackb(payload, raw=False)
        if not isinstance(obj, dict) or obj.get("released") != _RELEASE_VERSION:
            return None
        epoch = obj.get("epoch")
    except (WireError, ValueError) as exc:
        log.warning("ignored a release announcement on %s: %s", key[:200], exc)
        return None
    return (partition, instance, epoch) if type(epoch) is int else None


def _ranges(partitions: Sequence[int]) -> str:
    """'0-3,7,9-10' for [0, 1, 2, 3, 7, 9, 10]."""
    out: list[str] = []
    ordered = sorted(partitions)
    start = prev = ordered[0] if ordered else 0
    for p in [*ordered[1:], None]:
        if p is not None and p == prev + 1:
            prev = p
            continue
        out.append(str(start) if start == prev else f"{start}-{prev}")
        if p is not None:
            start = prev = p
    return ",".join(out) if ordered else "-"


__all__ = ["Service", "WireError"]


def _named_fleet_and_robot(selector: str) -> tuple[str | None, str | None]:
    """The fleet and robot chunks of a query's selector when they hold no wildcard."""
    chunks = [*selector.removeprefix(f"{keys.KEY_PREFIX}/").split("/"), "", ""]

    def plain(chunk: str) -> str | None:
        return chunk if chunk and not {"*", "$"} & set(chunk) else None

    fleet = plain(chunks[0])
    return fleet, plain(chunks[1]) if fleet is not None else None

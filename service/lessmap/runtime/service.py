"""The partition service: Zenoh declarations, shards, queries, lifecycle.

Threads: Zenoh's own (callbacks: enqueue only), one worker per shard, one query server, and
the caller's (``Service.start``/``stop``; ``serve`` parks it on a stop event). Callbacks never
call Zenoh or block; queries are answered from the query thread under the shard's lock.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import zlib
from typing import TYPE_CHECKING

import zenoh
from prometheus_client import start_http_server

from lessmap import __version__
from lessmap.errors import ConfigError
from lessmap.runtime.budget import EdgeLedger, SessionAdmission
from lessmap.runtime.metrics import ServiceMetrics
from lessmap.runtime.outbox import Outbox
from lessmap.runtime.sessions import SessionTable
from lessmap.runtime.shard import CATCHUP_DONE, RECOVERED, Inbound, Shard
from lessmap.runtime.store import CheckpointStore, StoreError
from lessmap.runtime.zenoh_config import service_config
from lessmap.settings import EMBEDDED_ENDPOINT
from lessmap_schemas import keys
from lessmap_schemas.codec import encode, encoding
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.messages import Health, SessionState, Submap

if TYPE_CHECKING:
    from collections.abc import Sequence
    from wsgiref.simple_server import WSGIServer

    from lessmap.runtime.sessions import CatchupRequest
    from lessmap.settings import ServiceSettings

log = logging.getLogger(__name__)

_QUEUE_BYTES_PER_SHARD = 256 * 1024 * 1024
_QUIET_S = 0.3  # no sample for this long: the inbound path has settled


class Service:
    """One lessmap service instance on a Zenoh session."""

    def __init__(self, settings: ServiceSettings, zenoh_cfg: Sequence[str] = ()) -> None:
        self.settings = settings
        self.metrics = ServiceMetrics()
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
        self._last_sample_s = 0.0
        self.metrics_port: int | None = None

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
            msg = f"{exc} (give --state-dir a writable folder, or --memory-only)"
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
        )
        params = s.partition_params()
        ledger = EdgeLedger(s.workers, s.max_edges_total)
        admission = SessionAdmission(s.new_sessions_per_s_per_fleet, s.new_sessions_burst)
        for index in range(s.workers):
            table = SessionTable(
                params,
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
                )
            )
        for shard in self._shards:
            shard.start()
        self._query_thread.start()
        any_robot = f"{keys.KEY_PREFIX}/*/*"
        self._declared.append(session.declare_queryable(f"{any_robot}/state", self._queries.put))
        self._declared.append(
            session.declare_queryable(f"{any_robot}/submaps/*", self._queries.put)
        )
        self._declared.append(session.declare_queryable(keys.health(s.instance), self._queries.put))
        # A plain subscriber; catch-up is an explicit query of the robot's publication cache
        # (``_request_catchup``), sent by the worker when its session table holds frames
        # beyond a gap. An AdvancedSubscriber with history was tried and is not used: the
        # robots' publishers have no sample miss detection (no sequence numbers), so it
        # orders each publisher's samples by timestamp and dropped history older than a
        # live sample that overtook it (frame 0 of a new session, then others), and with
        # ``detect_late_publishers`` on a wildcard every new robot costs a history query of
        # its whole cache. The query below is asked only on a gap, for one robot, and the
        # table puts what comes back in seq order itself.
        self._declared.append(session.declare_subscriber(f"{any_robot}/frames", self._on_sample))
        self._token = session.liveliness().declare_token(keys.instance_token(s.instance))
        if s.metrics_port is not None:
            server, _thread = start_http_server(
                s.metrics_port, addr=s.metrics_addr, registry=self.metrics.registry
            )
            self._metrics_server = server
            self.metrics_port = server.server_port
        log.info(
            "lessmap %s serving as %s (%s, %d shard(s), profile %s)%s",
            __version__,
            s.instance,
            "embedded router on tcp/127.0.0.1:7447" if s.embedded else "joined Zenoh network",
            s.workers,
            s.profile,
            f", metrics on http://{s.metrics_addr}:{self.metrics_port}/metrics"
            if self.metrics_port is not None
            else "",
        )
        if self.store.path is None:
            log.info("sessions live in memory only (--memory-only): a restart loses them")
        else:
            log.info("session checkpoints in %s", self.store.path)
            self._check_catchup_budget()

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
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline and time.monotonic() - self._last_sample_s < _QUIET_S:
            time.sleep(0.02)

    # -- receive path (Zenoh callback: enqueue only) ----------------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        shard = self._shard_of(key)
        if shard is None:
            return  # another instance's robot (static sharding of the fleet by key hash)
        self._last_sample_s = time.monotonic()
        self.metrics.frames_received.inc()
        payload = sample.payload
        if len(payload) > self.settings.limits.max_payload_bytes:
            # Decided here, before copying the bytes: a huge sample never reaches a queue.
            limit = self.settings.limits.max_payload_bytes
            self._reject_on_receipt(shard, key, f"payload of {len(payload)} bytes exceeds {limit=}")
            return
        if not shard.offer(Inbound(time.monotonic(), key, payload.to_bytes())):
            if shard.stopping:
                detail = "the service is stopping; frame not taken (a restart recovers it)"
            else:
                depth = self.settings.queue_depth
                detail = f"shard {shard.index} queue full ({depth=}); frame dropped"
            self._reject_on_receipt(shard, key, detail)

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
        if session is None:
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

    def _shard_of(self, key: str) -> Shard | None:
        """Return the shard that owns a robot's key, or None when another instance does.

        One hash decides both levels: ``h % shard_count`` picks the instance (``--shard I/N``),
        the rest picks the worker inside it, so a robot always lands in the same place.
        """
        digest = zlib.crc32(key.encode())
        count = self.settings.shard_count
        if digest % count != self.settings.shard_index:
            return None
        return self._shards[(digest // count) % len(self._shards)]

    @staticmethod
    def _reject_on_receipt(shard: Shard, key: str, detail: str) -> None:
        # Runs on Zenoh's thread: no Zenoh calls here. Hand the note to the shard, whose
        # worker publishes it as an Error on the robot's key.
        shard.note_rejection(key, ErrorCode.LIMIT_EXCEEDED, detail)

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
        is_submap = "/submaps/" in text
        for shard in self._shards:
            with shard.lock:
                robots = shard.table.robots()
                for fleet, robot in robots:
                    if is_submap:
                        self._reply_submaps(query, shard, fleet, robot)
                        continue
                    key = keys.state(fleet, robot)
                    if not selector.intersects(zenoh.KeyExpr(key)):
                        continue
                    state = shard.table.state(fleet, robot)
                    if state is not None:
                        query.reply(
                            key, encode(state), encoding=zenoh.Encoding(encoding(SessionState))
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
        )
        query.reply(
            keys.health(self.settings.instance),
            encode(health),
            encoding=zenoh.Encoding(encoding(Health)),
        )


__all__ = ["Service", "WireError"]

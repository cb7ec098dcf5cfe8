"""The partition service's lifecycle: open, build the parts, start them, stop them in order.

Threads: Zenoh's own (callbacks: enqueue only), one worker per shard (the only owner of
its session table), the receiver, the query server (``queries.py``), the ownership thread
and its heartbeat (``membership.py``), the store's writer, and the caller's
(``Service.start``/``stop``; ``serve`` parks it on a stop event).

Invariants:

1. Everything put on Zenoh leaves through the outbox (``outbox.py``).
2. The stop lets the input settle, stops following ownership changes, undeclares the
   frames subscribers and sweeps once more, then each shard drains and closes its own
   sessions (checkpointed, or closed when memory-only) before the store closes.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import zenoh
from prometheus_client import start_http_server

from lessmap import __version__
from lessmap.config.partitioning import area_params
from lessmap.config.settings import EMBEDDED_ENDPOINT
from lessmap.core.segmenter import Method
from lessmap.errors import ConfigError
from lessmap.runtime.budget import EdgeLedger, SessionAdmission
from lessmap.runtime.caches import CacheQueries
from lessmap.runtime.heavy import HeavyLane
from lessmap.runtime.membership import Membership
from lessmap.runtime.metrics import ServiceMetrics
from lessmap.runtime.outbox import EgressPolicy, Outbox
from lessmap.runtime.ownership import Ownership
from lessmap.runtime.queries import QueryServer
from lessmap.runtime.receiver import Receiver
from lessmap.runtime.replication import Replication
from lessmap.runtime.sessions.policy import (
    CatchupPolicy,
    DurabilityPolicy,
    Identity,
    Segmenting,
    SessionLimits,
    SharedBudgets,
)
from lessmap.runtime.sessions.table import SessionTable
from lessmap.runtime.shard import Shard, ShardPolicy
from lessmap.runtime.store import CheckpointStore, StoreError
from lessmap.runtime.zenoh_config import service_config
from lessmap_schemas import keys
from lessmap_schemas.errors import WireError
from lessmap_schemas.partition import PARTITIONS, partition_of

if TYPE_CHECKING:
    from collections.abc import Sequence
    from wsgiref.simple_server import WSGIServer

    from lessmap.config.settings import ServiceSettings

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
        self._receiver: Receiver | None = None
        self._queries: QueryServer | None = None
        self._membership: Membership | None = None
        self._declared: list[zenoh.Queryable[None]] = []
        self._metrics_server: WSGIServer | None = None
        self.store = CheckpointStore(
            None if settings.memory_only else settings.resolved_state_dir(),
            retention_s=settings.state_retention_s,
            max_bytes=settings.state_max_bytes,
        )
        self.metrics_port: int | None = None
        self.ownership = Ownership(settings.instance, freeze_s=settings.fence_after_s)
        self._replication = Replication(
            self.store, self.ownership, self.metrics, fetch_wait_s=settings.handover_fetch_s
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
        ownership = self.ownership
        self._outbox = outbox = Outbox(
            session,
            self.metrics,
            instance=s.instance,
            policy=EgressPolicy(
                transition_cache=s.transition_cache,
                max_publishers=s.max_sessions,
                error_rate_per_s=s.error_rate_per_s,
                error_burst=s.error_burst,
            ),
            epoch_for=ownership.epoch_for,
            replicate=self._replicates,
            store=self.store,
            release_memory=self.store.release_memory_soon,
        )
        caches = CacheQueries(
            session,
            ownership.owns,
            max_payload_bytes=s.limits.max_payload_bytes,
            wait_s=s.catchup_wait_s,
        )
        self._shards = self._build_shards(outbox, caches)
        self._receiver = receiver = Receiver(
            self._shards,
            self.metrics,
            max_payload_bytes=s.limits.max_payload_bytes,
            queue_depth=s.queue_depth,
            owned=lambda p: ownership.epoch_of(p) is not None,
        )
        self._queries = queries = QueryServer(
            s,
            self._shards,
            ownership,
            self._replication,
            self.metrics,
            lambda: outbox.frames_applied,
        )
        for shard in self._shards:
            shard.start()
        receiver.start()
        queries.start()
        # Metrics before any declaration: frames can arrive as soon as a partition is taken.
        if s.metrics_port is not None:
            try:
                server, _thread = start_http_server(
                    s.metrics_port, addr=s.metrics_addr, registry=self.metrics.registry
                )
            except OSError as exc:
                msg = (
                    f"cannot serve metrics on {s.metrics_addr}:{s.metrics_port}: "
                    f"{exc.strerror or exc}; choose another --metrics-port"
                )
                raise ConfigError(msg) from exc
            self._metrics_server = server
            self.metrics_port = server.server_port
        any_robot = f"{keys.KEY_PREFIX}/*/*"
        for key in (
            f"{any_robot}/state",
            f"{any_robot}/areas",
            f"{any_robot}/submaps/*",
            keys.health(s.instance),
            keys.checkpoints(),  # every instance answers for those it holds (a new owner asks)
        ):
            self._declared.append(session.declare_queryable(key, queries.put))
        # Frames: subscribed as partitions are taken (``membership.py``). Catch-up is an
        # explicit query of the robot's publication cache (``caches.py``), asked only on a
        # gap, for one robot (docs/decisions/0005-catch-up-by-query.md).
        self._membership = Membership(
            s, session, ownership, self._shards, receiver, self._replication, caches, outbox
        )
        self._membership.start()
        log.info(
            "lessmap %s serving as %s (%s, method %s, %d shard(s), profile %s, %d of %d "
            "partitions)%s",
            __version__,
            s.instance,
            "embedded router on tcp/127.0.0.1:7447" if s.embedded else "joined Zenoh network",
            s.method,
            s.shards,
            s.profile,
            len(ownership.owned()),
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

    def _build_shards(self, outbox: Outbox, caches: CacheQueries) -> list[Shard]:
        """One session table and one worker per ``shards``, sharing the instance's budgets."""
        s = self.settings
        segmenting = Segmenting(
            params=s.partition_params(),
            method=Method(s.method),
            area_params=area_params(s),
            omits_empty_frames=s.omits_empty_frames,
        )
        limits = SessionLimits(
            max_sessions=max(1, -(-s.max_sessions // s.shards)),
            max_nodes=s.max_nodes_per_session,
            max_batch_frames=s.max_batch_frames,
            idle_timeout_s=s.session_idle_timeout_s,
            max_pairs_per_frame=s.max_pairs_per_frame,
            max_edges_per_session=s.max_edges_per_session,
        )
        durability = DurabilityPolicy(
            every_frames=s.checkpoint_every_frames, interval_s=s.checkpoint_interval_s
        )
        # Catch-up with a store only: memory-only keeps today's immediate SEQ_GAP.
        catchup = CatchupPolicy(
            max_frames=0 if self.store.path is None else s.catchup_max_frames,
            wait_s=s.catchup_wait_s,
        )
        identity = Identity(instance=s.instance, epoch_of=self.ownership.last_epoch)
        ledger = EdgeLedger(2 * s.shards, s.max_edges_total)  # a slot per table
        admission = SessionAdmission(s.new_sessions_per_s_per_fleet, s.new_sessions_burst)
        policy = ShardPolicy(
            queue_depth=s.queue_depth,
            queue_bytes=_QUEUE_BYTES_PER_SHARD,
            linger_s=s.batch_linger_ms / 1000.0,
            quantum=s.fair_quantum,
            coalesce_after_s=s.coalesce_after_ms / 1000.0,
        )

        def shard(index: int, heavy: HeavyLane[Shard] | None, heavy_of: int | None) -> Shard:
            table = SessionTable(
                segmenting,
                limits,
                identity=identity,
                durability=durability,
                catchup=catchup,
                budgets=SharedBudgets(ledger=ledger, slot=index, admission=admission),
                store=self.store,
            )
            return Shard(
                index,
                table,
                outbox,
                limits=s.limits.wire_limits(),
                policy=replace(policy, heavy_of=heavy_of),
                request_catchup=caches.request_catchup,
                owns=self.ownership.owns,
                heavy=heavy,
            )

        shards = []
        for index in range(s.shards):
            heavy = None
            if s.heavy_decision_ms > 0:  # its heavy lane: a shard of its own, fed by it
                heavy = HeavyLane(shard(s.shards + index, None, index), s.heavy_decision_ms)
            shards.append(shard(index, heavy, None))
        return shards

    def _replicates(self, fleet: str, robot: str) -> bool:
        """True when a robot's checkpoints also go to the standby: owned here, not alone."""
        ownership = self.ownership
        return (
            len(ownership.live) >= 2 and ownership.epoch_of(partition_of(fleet, robot)) is not None
        )

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
        if self._membership is not None:
            self._membership.stop()
        if self._receiver is not None:
            self._receiver.stop()  # the last sweep takes what the channels still hold
        self._replication.stop_standing_by()
        for declared in reversed(self._declared):
            declared.undeclare()
        self._declared.clear()
        deadline = time.monotonic() + timeout_s
        for shard in self._shards:
            # The worker drains, then checkpoints (or closes) its sessions and publishes.
            shard.stop(max(0.1, deadline - time.monotonic()))
        self.store.close()
        if self._queries is not None:
            self._queries.stop()
        if self._membership is not None:
            self._membership.undeclare_token()
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


__all__ = ["Service", "WireError"]

"""Everything the service puts on Zenoh: transitions, errors, states, checkpoints, releases.

Invariants:

1. All egress leaves here, from the shard workers (and the ownership thread's release
   announcements), never from a Zenoh callback or the store's writer thread.
2. The fence: nothing about a robot is published unless ``epoch_for(fleet, robot)`` gives
   the epoch of its partition (owned, and not frozen since); every message carries it.
3. Checkpoints come last: an outcome's records are saved, and shipped to the standby, only
   after its transitions were put, and never for a session with a fenced transition. Zenoh
   delivers one session's puts in order, so a checkpoint that reached another instance
   implies the transitions it covers reached the router.
4. Transitions go out through one ``AdvancedPublisher`` per robot with a cache, so a fleet
   app that joins late or misses samples recovers them; errors are rate-limited per robot.
5. No put waits for a consumer: every put drops rather than blocks on a full link
   (``docs/design/slow-consumers.md``); transitions travel at a priority of their own.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING

import msgpack
import zenoh
from zenoh import ext

from lessmap.runtime.memory import release_free_memory
from lessmap.runtime.ratelimit import RateLimiter
from lessmap.runtime.sessions.durability import commit_checkpoints
from lessmap.runtime.sessions.wire import wire_transition
from lessmap_schemas import keys
from lessmap_schemas.codec import encode, encoding
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Error, SessionState, Transition
from lessmap_schemas.partition import partition_of

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.core.segmenter import SegmentChange
    from lessmap.runtime.metrics import ServiceMetrics
    from lessmap.runtime.record import SessionRecord
    from lessmap.runtime.sessions.model import Outcome, Rejection, RobotSession
    from lessmap.runtime.store import CheckpointStore
    from lessmap_schemas.errors import WireError

log = logging.getLogger(__name__)

_NOT_REJECTIONS = {ErrorCode.SEQ_GAP}  # reported, but the frame was applied
_DUPLICATES = {ErrorCode.DUPLICATE_SEQ}  # OUT_OF_ORDER counts as rejected, by reason
_TRANSITION_ENCODING = zenoh.Encoding(encoding(Transition))
_ERROR_ENCODING = zenoh.Encoding(encoding(Error))
_STATE_ENCODING = zenoh.Encoding(encoding(SessionState))
_INTERNAL_ENCODING = zenoh.Encoding("application/octet-stream")  # checkpoints, releases
# Invariant 5. A link that is full because one consumer does not read loses that consumer's
# copy; with BLOCK the router would stop forwarding this instance's puts to everyone.
_DROP = zenoh.CongestionControl.DROP
# Transitions on a priority nothing else of ours uses (so a blocking reply or a peer's
# BLOCK traffic on DATA cannot hold them up). Batched: a burst of one chunk's transitions
# fits one batch, where express ones each took one of the queue's two slots and dropped.
_TRANSITION_PRIORITY = zenoh.Priority.DATA_HIGH
RELEASE_VERSION = 1  # of the service-internal release announcement (``keys.released``)


@dataclass(frozen=True, slots=True, kw_only=True)
class EgressPolicy:
    """How much the outbox keeps and lets out: transition caches, publishers, error rate."""

    transition_cache: int
    max_publishers: int
    error_rate_per_s: float
    error_burst: int


def _never(_fleet: str, _robot: str) -> bool:
    return False


class Outbox:
    """Publishes outcomes of the shards and keeps the metrics in step."""

    def __init__(
        self,
        session: zenoh.Session,
        metrics: ServiceMetrics,
        *,
        instance: str,
        policy: EgressPolicy,
        epoch_for: Callable[[str, str], int | None] | None = None,
        replicate: Callable[[str, str], bool] = _never,
        store: CheckpointStore | None = None,
        release_memory: Callable[[], object] = release_free_memory,
    ) -> None:
        self.metrics = metrics
        self._store = store  # where the outcomes' checkpoints go once published
        # True for a robot whose checkpoints go to the standby too (its partition is owned
        # here and another instance runs).
        self._replicate = replicate
        # After sessions left memory (evicted, handed over): give their memory back. The
        # service passes the store's ``release_memory_soon`` (after their records are written).
        self._release_memory = release_memory
        # The fence (invariant 2); a lone instance without ownership owns everything.
        self._epoch_for = epoch_for if epoch_for is not None else (lambda _fleet, _robot: 1)
        self._session = session
        self._instance = instance
        self._cache = policy.transition_cache
        self._max_publishers = policy.max_publishers
        self._publishers: OrderedDict[tuple[str, str], ext.AdvancedPublisher] = OrderedDict()
        self._publishers_lock = threading.Lock()
        self._limiter = RateLimiter(policy.error_rate_per_s, policy.error_burst)
        self._limiter_lock = threading.Lock()
        self._service_errors_key = keys.service_errors(instance)
        self.frames_applied = 0  # for the health answer (prometheus counters are write-only)

    # -- outcomes ----------------------------------------------------------------------------

    def publish(self, outcome: Outcome, now_s: float) -> None:
        """Put everything a batch produced and count it."""
        m = self.metrics
        m.frames_applied.inc(outcome.frames_applied)
        self.frames_applied += outcome.frames_applied
        m.frames_duplicate.inc(outcome.frames_duplicate)
        m.frames_missing.inc(outcome.frames_missing)
        m.frames_recovered.inc(outcome.frames_recovered)
        decisions = outcome.decisions
        if decisions:  # counted per outcome: a chunk of turns decides for many robots
            m.decisions.inc(len(decisions))
            m.decision_seconds.observe_many([seconds for seconds, _batch in decisions])
            m.coalesced_batches.inc(sum(1 for _seconds, batch in decisions if batch > 1))
        for key, exc in outcome.failures:
            log.error("session %s/%s reset after an internal error", *key, exc_info=exc)
        for session in outcome.opened:
            m.sessions_opened.inc()
            m.sessions.inc()
            log.info(
                "session opened: %s/%s %s",
                session.fleet,
                session.robot,
                session.session,
                extra={
                    "event": "session_opened",
                    "fleet": session.fleet,
                    "robot": session.robot,
                    "session": session.session,
                },
            )
        for session in outcome.resumed:
            m.sessions_resumed.inc()
            m.sessions.inc()
            log.info(
                "session resumed from the state store: %s/%s %s at seq %s",
                session.fleet,
                session.robot,
                session.session,
                session.last_seen_seq,
                extra={
                    "event": "session_resumed",
                    "fleet": session.fleet,
                    "robot": session.robot,
                    "session": session.session,
                },
            )
        if outcome.evicted:
            m.sessions_evicted.inc(outcome.evicted)
            m.sessions.dec(outcome.evicted)
        for state in outcome.suspended:  # stop with a store: the session lives on
            m.sessions.dec()
            self._put_state(state)
        for session, transition in outcome.transitions:
            self._put_transition(session, transition)
        for rejection in outcome.rejections:
            self._count_rejection(rejection.code)
            self._put_error(rejection, now_s)
        for state, cause in outcome.closed:
            m.sessions.dec()
            m.sessions_closed.labels(cause=cause).inc()
            log.info(
                "session closed (%s): %s/%s %s after %d frames, %d transitions",
                cause,
                state.fleet,
                state.robot,
                state.session,
                state.frames_applied,
                state.transitions,
                extra={
                    "event": "session_closed",
                    "cause": cause,
                    "fleet": state.fleet,
                    "robot": state.robot,
                    "session": state.session,
                    "frames_applied": state.frames_applied,
                    "transitions": state.transitions,
                },
            )
            self._put_state(state)
        if self._store is not None and outcome.checkpoints:
            shipped = [record for session, record in outcome.checkpoints if not session.fenced]
            withheld = commit_checkpoints(outcome, self._store)
            if withheld:
                m.checkpoints_withheld.inc(withheld)
            self._ship(shipped)
        if outcome.evicted:
            self._release_memory()  # evicted graphs are freed (and saved): let it shrink

    def _ship(self, records: list[SessionRecord]) -> None:
        """Put the checkpoints just saved for the standby (invariant 3)."""
        for record in records:
            if not self._replicate(record.fleet, record.robot):
                continue  # alone, or not ours (handed over)
            p = partition_of(record.fleet, record.robot)
            try:
                self._session.put(
                    keys.checkpoints(p, record.fleet, record.robot),
                    record.to_bytes(),
                    encoding=_INTERNAL_ENCODING,
                    congestion_control=_DROP,  # the standby also fetches on a take-over
                )
                self.metrics.checkpoints_shipped.inc()
            except zenoh.ZError as exc:
                log.warning("could not ship the checkpoint of %s/%s: %s", *record.key, exc)

    def announce_released(self, partition: int, epoch: int) -> None:
        """Say that a partition was handed over, with the epoch it had (a joiner waits)."""
        payload = msgpack.packb({"released": RELEASE_VERSION, "epoch": epoch})
        try:
            key = keys.released(partition, self._instance)
            self._session.put(key, payload, encoding=_INTERNAL_ENCODING, congestion_control=_DROP)
        except zenoh.ZError as exc:
            log.warning("could not announce the release of partition %d: %s", partition, exc)

    def _count_rejection(self, code: ErrorCode) -> None:
        if code in _NOT_REJECTIONS or code in _DUPLICATES:
            return  # counted as missing / duplicate frames by the table
        self.metrics.frames_rejected.labels(reason=code.value).inc()

    def reject_unattributed(self, key: str, exc: WireError) -> None:
        """Report a sample whose key names no valid robot (no robot errors key to use)."""
        self.metrics.frames_rejected.labels(reason=exc.code.value).inc()
        with self._limiter_lock:
            allowed, suppressed = self._limiter.allow(None, time.monotonic())
        if not allowed:
            self.metrics.errors_suppressed.inc()
            return
        log.warning("rejected a sample on %r: %s", key[:200], exc)
        error = Error(
            fleet=None,
            robot=None,
            session=None,
            code=exc.code,
            detail=_detail(f"key {key[:200]!r}: {exc}", suppressed),
            seq=None,
            stamp_s=time.time(),
            instance=self._instance,
            epoch=None,
        )
        self._put(self._service_errors_key, encode(error), _ERROR_ENCODING)

    def report_store_changes(self) -> None:
        """Publish each change of the store's durability once (shard 0 calls it each loop).

        An ``Error`` on the instance's ``@/errors`` key, like any fault of the instance
        rather than of one robot; the gauge and the counter follow it.
        """
        if self._store is None or self._store.path is None:
            return
        health = self._store.health
        changes = health.take_changes()
        self.metrics.store_durable.set(0 if health.lost else 1)
        for lost, detail in changes:
            if lost:
                self.metrics.store_losses.inc()
            error = Error(
                fleet=None,
                robot=None,
                session=None,
                code=ErrorCode.DURABILITY_LOST if lost else ErrorCode.DURABILITY_BACK,
                detail=_detail(detail, 0),
                seq=None,
                stamp_s=time.time(),
                instance=self._instance,
                epoch=None,
            )
            self._put(self._service_errors_key, encode(error), _ERROR_ENCODING)

    # -- puts --------------------------------------------------------------------------------

    def _fenced(self, fleet: str, robot: str) -> int | None:
        """The epoch to publish under, or None (counted): this instance may not speak."""
        epoch = self._epoch_for(fleet, robot)
        if epoch is None:
            self.metrics.events_fenced.inc()
        return epoch

    def _put_state(self, state: SessionState) -> None:
        epoch = self._fenced(state.fleet, state.robot)
        if epoch is None:
            return
        if state.epoch != epoch:
            state = state.model_copy(update={"epoch": epoch})
        self._put(keys.state(state.fleet, state.robot), encode(state), _STATE_ENCODING)

    def _put_transition(self, session: RobotSession, change: SegmentChange) -> None:
        epoch = self._fenced(session.fleet, session.robot)
        if epoch is None:
            session.fenced = True  # its checkpoints would skip this transition for good
            return
        message = wire_transition(session, change, self._instance, epoch)
        transition = change.transition
        self.metrics.transitions.labels(reason=message.reason).inc()
        log.debug(
            "->> TRANSITION %s/%s seq=%d %s",
            session.fleet,
            session.robot,
            transition.seq,
            message.reason,
        )
        publisher = self._publisher(session.fleet, session.robot)
        try:
            publisher.put(encode(message))
        except zenoh.ZError:
            log.exception("could not publish a transition of %s/%s", session.fleet, session.robot)

    def _publisher(self, fleet: str, robot: str) -> ext.AdvancedPublisher:
        key = (fleet, robot)
        with self._publishers_lock:
            publisher = self._publishers.get(key)
            if publisher is not None:
                self._publishers.move_to_end(key)
                return publisher
            publisher = ext.declare_advanced_publisher(
                self._session,
                keys.transitions(fleet, robot),
                encoding=_TRANSITION_ENCODING,
                congestion_control=_DROP,
                priority=_TRANSITION_PRIORITY,
                cache=ext.CacheConfig(self._cache),
                # Sequence numbers and heartbeats let an AdvancedSubscriber notice a missed
                # transition and fetch it from the cache instead of silently skipping it.
                sample_miss_detection=ext.MissDetectionConfig(
                    heartbeat=None, sporadic_heartbeat=1.0
                ),
                publisher_detection=True,
            )
            self._publishers[key] = publisher
            if len(self._publishers) > self._max_publishers:
                _, oldest = self._publishers.popitem(last=False)
                oldest.undeclare()
            return publisher

    def _put_error(self, rejection: Rejection, now_s: float) -> None:
        epoch = self._fenced(rejection.fleet, rejection.robot)
        if epoch is None:
            return
        with self._limiter_lock:
            # One bucket per robot and code: a flood of one kind of fault never hides the
            # first report of another.
            bucket = (rejection.fleet, rejection.robot, rejection.code)
            allowed, suppressed = self._limiter.allow(bucket, now_s)
        if not allowed:
            self.metrics.errors_suppressed.inc()
            return
        log.warning(
            "%s/%s %s: %s", rejection.fleet, rejection.robot, rejection.code.value, rejection.detail
        )
        error = Error(
            fleet=rejection.fleet,
            robot=rejection.robot,
            session=rejection.session,
            code=rejection.code,
            detail=_detail(rejection.detail, suppressed),
            seq=rejection.seq,
            stamp_s=time.time(),
            instance=self._instance,
            epoch=epoch,
        )
        self.metrics.errors_published.inc()
        self._put(keys.errors(rejection.fleet, rejection.robot), encode(error), _ERROR_ENCODING)

    def _put(self, key: str, payload: bytes, encoding_: zenoh.Encoding) -> None:
        try:
            self._session.put(key, payload, encoding=encoding_, congestion_control=_DROP)
        except zenoh.ZError:
            log.exception("could not put on %s", key)

    def close(self) -> None:
        """Undeclare every transitions publisher."""
        with self._publishers_lock:
            for publisher in self._publishers.values():
                publisher.undeclare()
            self._publishers.clear()


def _detail(text: str, suppressed: int) -> str:
    if suppressed:
        text = f"{text} ({suppressed} similar error(s) suppressed by the rate limit)"
    return text[:1024]

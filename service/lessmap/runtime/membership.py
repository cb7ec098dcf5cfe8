"""Membership: joining the instances, taking and handing over partitions, freezes.

Invariants (schemas/README.md section 2a; ``docs/decisions/0003-shard-actor.md``):

1. One thread, ``lessmap-ownership``, carries out every change of ownership; Zenoh's
   callbacks only enqueue for it.
2. Taking a partition: fetch its newest checkpoints, take an epoch, subscribe to its
   frames, probe the robots' caches; a robot's next frame resumes its session.
3. Handing one over: the shards apply what already arrived for it (a command behind those
   samples), the fence closes, the frames are unsubscribed, the shards checkpoint and drop
   its sessions (a command each), the release is announced.
4. Joining while others run: hold the won partitions' frames, declare the token, wait for
   each release (bounded), then fetch and take, the held frames first (as probes).
5. A process frozen past the fence drops every partition and rejoins as a joiner does; so
   does a client without a router for as long (another instance may have taken over).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from concurrent.futures import wait
from typing import TYPE_CHECKING

import msgpack
import zenoh

from lessmap.runtime.outbox import RELEASE_VERSION
from lessmap.runtime.receiver import EVERY_PARTITION
from lessmap_schemas import keys
from lessmap_schemas.errors import WireError
from lessmap_schemas.partition import partition_of

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from lessmap.config.settings import ServiceSettings
    from lessmap.runtime.caches import CacheQueries
    from lessmap.runtime.outbox import Outbox
    from lessmap.runtime.ownership import Change, Ownership
    from lessmap.runtime.receiver import Receiver
    from lessmap.runtime.replication import Replication
    from lessmap.runtime.shard import Shard

log = logging.getLogger(__name__)

_HEARTBEAT_S = 0.1  # freeze detection (fence_after_s is far above it)
_LEAVE_CONFIRM_S = 0.25  # a token that went is checked again this much later
# A hand-over first lets the shards apply what already arrived for the partitions, this long
# at most: well below handover_release_s, so the joining owner still gets the release.
_DRAIN_BEFORE_HANDOVER_S = 1.0
_ROUTER_WAIT_S = 10.0  # after a freeze, how long a client waits for its router again
# Back from a cut or a freeze, how long to wait for the instances known before it to show
# again: a restarted router learns the others' tokens from its peers a while after it links.
_REJOIN_WAIT_S = 10.0


class Membership:
    """Carries out what ``Ownership`` computes, on the ownership thread."""

    def __init__(
        self,
        settings: ServiceSettings,
        session: zenoh.Session,
        ownership: Ownership,
        shards: Sequence[Shard],
        receiver: Receiver,
        replication: Replication,
        caches: CacheQueries,
        outbox: Outbox,
    ) -> None:
        self._settings = settings
        self._session = session
        self._ownership = ownership
        self._shards = tuple(shards)
        self._receiver = receiver
        self._replication = replication
        self._caches = caches
        self._outbox = outbox
        self._metrics = outbox.metrics
        self._token: zenoh.LivelinessToken | None = None
        self._frame_subs: dict[int, zenoh.Subscriber[zenoh.Handler[zenoh.Sample]]] = {}
        self._liveliness_sub: zenoh.Subscriber[None] | None = None
        self._release_sub: zenoh.Subscriber[None] | None = None  # while a join waits
        # Release announcements of the former owners, while this instance waits for them
        # (a join only): the subscriber's callback only enqueues.
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
        """Join the instances and take this instance's partitions, then follow changes.

        Alone, the instance takes every partition first (frames subscriptions, checkpoints,
        cache probes), then declares its token: declarations reach every client in order,
        so one that sees the token already routes its frames here. With others running, it
        joins (invariant 4). The live tokens are asked before the liveliness subscriber is
        declared: with a history subscriber declared first, zenoh 1.x answered the get with
        the local token only. The subscriber follows at once, before the take, so an
        instance that leaves meanwhile is not missed; its history repeats what the get saw
        (joins are idempotent), and its changes wait for the ownership thread.
        """
        live = self._live_instances()
        log.info("live instances: %s", ", ".join(sorted(set(live))))
        self._liveliness_sub = self._session.liveliness().declare_subscriber(
            keys.instances(), self._on_liveliness, history=True
        )
        self._ownership.start_clock()
        self._heartbeat_thread.start()
        change = self._ownership.set_live(live, arriving=True)
        if change.handed_by:
            self._join(change)
        else:
            self._apply(change)
            self._declare_token()
        self._control_thread.start()

    def stop(self) -> None:
        """Stop following changes; undeclare the liveliness and frames subscribers."""
        self._heartbeat_stop.set()
        self._control.put(None)
        if self._control_thread.is_alive():
            self._control_thread.join(max(1.0, self._settings.handover_fetch_s + 1.0))
        if self._liveliness_sub is not None:
            self._liveliness_sub.undeclare()
            self._liveliness_sub = None
        self._stop_listening()
        for frames_sub in self._frame_subs.values():
            frames_sub.undeclare()
        self._frame_subs.clear()

    def undeclare_token(self) -> None:
        """Leave: the other instances take this one's partitions over."""
        if self._token is not None:
            self._token.undeclare()
            self._token = None

    def _declare_token(self) -> None:
        self._token = self._session.liveliness().declare_token(
            keys.instance_token(self._settings.instance)
        )

    # -- the ownership thread ------------------------------------------------------------------

    def _on_liveliness(self, sample: zenoh.Sample) -> None:  # Zenoh's thread: enqueue only
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        kind = "join" if sample.kind == zenoh.SampleKind.PUT else "leave"
        self._control.put((kind, name))

    def _on_released(self, sample: zenoh.Sample) -> None:  # Zenoh's thread: enqueue only
        self._releases.put((str(sample.key_expr), sample.payload.to_bytes()))

    def _on_replica(self, sample: zenoh.Sample) -> None:  # Zenoh's thread: enqueue only
        self._control.put(("checkpoint", (str(sample.key_expr), sample.payload.to_bytes())))

    def _run_heartbeat(self) -> None:
        cut_since: float | None = None  # since when a client has had no router
        reported = False
        while not self._heartbeat_stop.wait(_HEARTBEAT_S):
            if self._ownership.tick():
                self._control.put(("frozen", None))
            if not self._without_router():
                cut_since, reported = None, False
                continue
            now = time.monotonic()
            cut_since = now if cut_since is None else cut_since
            if not reported and now - cut_since > self._settings.fence_after_s:
                reported = True  # invariant 5: once per cut
                self._control.put(("cut off", None))

    def _run_control(self) -> None:
        while True:
            item = self._control.get()
            if item is None:
                return
            kind, value = item
            try:
                if kind == "join":
                    self._apply(self._ownership.join(str(value)))
                elif kind == "leave":
                    if self._confirm_leave(str(value)):
                        self._apply(self._ownership.leave(str(value)))
                elif kind == "checkpoint":
                    self._replication.take_replica(*value)  # type: ignore[misc]
                elif kind == "frozen":
                    self._after_freeze()
                elif kind == "cut off":
                    self._after_cut_off()
            except Exception:
                # A bug must not stop ownership changes: log it, keep going.
                log.exception("ownership change %s %s failed", kind, value)

    def _live_instances(self) -> list[str]:
        """Ask the network for the live instance tokens (this one included)."""
        names = [self._settings.instance]
        try:
            replies = self._session.liveliness().get(keys.instances(), timeout=1.0)
            for reply in replies:
                if reply.ok is not None:
                    names.append(str(reply.ok.key_expr).rsplit("/", 1)[-1])
        except zenoh.ZError as exc:
            log.warning("could not list the live instances: %s", exc)
        return names

    def _confirm_leave(self, name: str) -> bool:
        """True when an instance whose token went is still gone a moment later.

        Taking partitions over is the risky direction (two owners for a moment), so a leave
        is checked: a client that loses its router sees every other token go and come back
        when it reconnects (after a freeze, a network blip). A client without a router sees
        nothing reliable and takes nothing.
        """
        time.sleep(_LEAVE_CONFIRM_S)
        if self._without_router():
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
            self._settings.instance,
            self._settings.fence_after_s,
        )
        known = self._ownership.live
        self._hand_over(sorted(self._ownership.owned()))
        self._replication.stop_standing_by()
        self._listen_for_releases()
        self._wait_for_router()
        self._rejoin(known)

    def _after_cut_off(self) -> None:
        """No router past the fence: the others took this instance's partitions; drop them.

        Kept, its sessions would go on from where the cut left them while the instance that
        took over applied more: the partitions come back only as a joiner's do, from the
        checkpoints of whoever held them meanwhile (docs/design/faults.md).
        """
        log.warning(
            "%s had no router for more than %.1f s: every partition dropped (another "
            "instance may have taken them over); rejoining when a router is back",
            self._settings.instance,
            self._settings.fence_after_s,
        )
        known = self._ownership.live
        self._hand_over(sorted(self._ownership.owned()))
        self._replication.stop_standing_by()
        self._listen_for_releases()
        while self._without_router():  # unbounded: alone, it would take every partition
            if self._heartbeat_stop.wait(0.1):
                return
        # The others' tokens reach a client just after its link is back.
        if self._heartbeat_stop.wait(_LEAVE_CONFIRM_S):
            return
        self._rejoin(known)

    def _rejoin(self, known: frozenset[str]) -> None:
        # Back as a joiner comes (invariant 5): the partitions won again were taken over
        # meanwhile; taken at once, they would resume from this instance's old checkpoints.
        change = self._ownership.set_live(self._instances_back(known), arriving=True)
        if change.handed_by:
            self._join(change, declare_token=False)
        else:
            self._stop_listening()
            self._apply(change)

    def _instances_back(self, known: frozenset[str]) -> list[str]:
        """The live instances once those ``known`` before the cut show again (bounded).

        Seen alone too early, this instance would take every partition and resume them from
        its own old checkpoints, though another instance applied their frames meanwhile.
        """
        deadline = time.monotonic() + _REJOIN_WAIT_S
        while True:
            live = self._live_instances()
            missing = sorted(known - set(live))
            if not missing or self._heartbeat_stop.is_set():
                return live
            if time.monotonic() > deadline:
                log.warning(
                    "rejoining without %s: not seen %.0f s after the router came back",
                    ", ".join(missing),
                    _REJOIN_WAIT_S,
                )
                return live
            self._heartbeat_stop.wait(_LEAVE_CONFIRM_S)

    def _without_router(self) -> bool:
        """True for a client connected to no router: it sees no other instance's token."""
        return self._settings.mode == "client" and not list(self._session.info.routers_zid())

    def _wait_for_router(self) -> None:
        """After a freeze, wait (bounded) until a client is connected to a router again.

        A client whose router dropped it during the freeze sees no other token until it has
        reconnected: asked for the live instances before that, it would take every partition.
        """
        deadline = time.monotonic() + _ROUTER_WAIT_S
        while self._without_router():
            if time.monotonic() > deadline:
                log.warning(
                    "no router %.0f s after the freeze: taking partitions on what this "
                    "instance sees",
                    _ROUTER_WAIT_S,
                )
                return
            time.sleep(0.1)

    # -- changes -------------------------------------------------------------------------------

    def _join(self, change: Change, *, declare_token: bool = True) -> None:
        """Take partitions from the live instances that hold them (invariant 4).

        After a freeze or a cut the token is already declared: the others see it again as
        the session reconnects, and hand over at once; the releases are listened to from
        the cut on, or the joiner would wait out ``handover_release_s`` for each one.
        """
        if self._release_sub is None:
            self._listen_for_releases()
        try:
            held = sorted(change.handed_by)
            self._receiver.hold(held)
            self._subscribe_frames(held)
            if declare_token:
                self._declare_token()  # the former owners hand over when they see it
            self._apply(change)
        finally:
            self._stop_listening()

    def _listen_for_releases(self) -> None:
        while not self._releases.empty():  # announcements of an earlier join, already used
            self._releases.get_nowait()
        self._release_sub = self._session.declare_subscriber(keys.released(), self._on_released)

    def _stop_listening(self) -> None:
        if self._release_sub is not None:
            self._release_sub.undeclare()
            self._release_sub = None

    def _apply(self, change: Change) -> None:
        """Carry out a change of ownership (ownership thread, or ``start``)."""
        if not change:
            return
        self._hand_over(change.lost)
        for p in change.standby_lost:
            self._ownership.set_standby(p, on=False)
        self._replication.stop_standing_by(change.standby_lost)
        for p in change.standby_gained:
            self._ownership.set_standby(p, on=True)
            self._replication.stand_by(self._session, p, self._on_replica)
        if change.gained:
            self._take(change.gained, change.handed_by)
        self._metrics.partitions_owned.set(len(self._ownership.owned()))

    def _hand_over(self, partitions: Sequence[int]) -> None:
        """Apply what arrived, close the fence, unsubscribe, checkpoint, drop, announce."""
        if not partitions:
            return
        leaving = set(partitions)

        def of_leaving(fleet: str, robot: str) -> bool:
            return partition_of(fleet, robot) in leaving

        self._apply_arrived(of_leaving)
        epochs = self._ownership.owned()  # before the release: what the announcement names
        for p in partitions:
            self._ownership.release(p)
            sub = self._frame_subs.pop(p, None)
            if sub is not None:
                sub.undeclare()
        self._receiver.watch(self._frame_subs)
        now = time.monotonic()
        # Each shard checkpoints and drops the sessions, and publishes the counters and
        # checkpoints (the fence is closed), after any turn decided before the fence closed.
        dropped = sum(
            f.result() for f in [s.hand_over_sessions(of_leaving, now) for s in self._shards]
        )
        # The sessions' final records are in the store now (pending ones included, which the
        # checkpoint queries read): a new owner waiting for this fetches them next.
        if len(self._ownership.live) >= 2:  # alone: nobody takes them (a freeze dropped them)
            for p in partitions:
                epoch = epochs.get(p)
                if epoch is not None:  # else fenced by a freeze: nothing was decided
                    self._outbox.announce_released(p, epoch)
        self._metrics.partition_moves.labels(direction="out").inc(len(partitions))
        log.info(
            "handed over %d partition(s) (%d session(s) checkpointed): %s",
            len(partitions),
            dropped,
            ranges(partitions),
        )

    def _apply_arrived(self, wanted: Callable[[str, str], bool]) -> None:
        """Let the shards apply what arrived for partitions about to be handed over.

        A frame or end that reached this instance before the new owner subscribed reached
        nobody else (Zenoh forwarded it here before the new owner's token, which came after
        its subscription): dropped as foreign after the release, it would be lost but for
        the robot's cache, and a ``SessionEnd`` is never in a cache. The sweep puts what the
        channels hold on the shards' queues; each shard's drain command follows it there.
        Bounded: under overload what is left goes to the new owner's probe and catch-up.
        """
        self._receiver.sweep()
        futures = [shard.drain(wanted) for shard in self._shards]
        _done, pending = wait(futures, timeout=_DRAIN_BEFORE_HANDOVER_S)
        if pending:
            log.info("handing over with frames still queued: the new owner's probe follows")

    def _await_releases(self, handed_by: dict[int, str]) -> None:
        """Wait until each partition's former owner announced its release (bounded).

        On time out the take goes on as without a hand-shake (checkpoints as they are, the
        robots' caches for the rest): a former owner that does not answer must not keep the
        partitions unserved.
        """
        waiting = dict(handed_by)
        wait_s = self._settings.handover_release_s
        deadline = time.monotonic() + wait_s
        while waiting:
            try:
                key, payload = self._releases.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            release = read_release(key, payload)
            if release is not None and waiting.get(release[0]) == release[1]:
                del waiting[release[0]]
                self._ownership.saw_epoch(release[0], release[2])
        if waiting:
            self._metrics.handover_release_timeouts.inc(len(waiting))
            log.warning(
                "%d partition(s) taken without a release from %s within %.1f s: %s",
                len(waiting),
                ", ".join(sorted(set(waiting.values()))),
                wait_s,
                ranges(sorted(waiting)),
            )

    def _subscribe_frames(self, partitions: Sequence[int]) -> None:
        subs = self._frame_subs
        receiver = self._receiver
        if self._settings.frames_subscription == "all":
            # One subscription for good; the receiver keeps the owned partitions' frames.
            if EVERY_PARTITION not in subs:
                subs[EVERY_PARTITION] = self._session.declare_subscriber(
                    keys.frames_of_every_partition(), receiver.channel()
                )
        else:
            for p in partitions:
                if p not in subs:
                    subs[p] = self._session.declare_subscriber(
                        keys.frames_of_partition(p), receiver.channel()
                    )
        receiver.watch(subs)

    def _take(self, partitions: Sequence[int], handed_by: dict[int, str] | None = None) -> None:
        """Fetch the partitions' newest checkpoints, take epochs, subscribe to their frames.

        ``handed_by``: partitions a live former owner hands over; their checkpoints are
        fetched once it announced the release (``_await_releases``).
        """
        started = time.monotonic()
        if handed_by:
            self._await_releases({p: handed_by[p] for p in partitions if p in handed_by})
        fetched = self._replication.fetch(self._session, partitions)
        held = self._receiver.admit(partitions, self._ownership.acquire)
        self._subscribe_frames(partitions)
        if self._replication.store.path is not None:  # memory-only: gaps reported at once
            for p in partitions:
                self._caches.probe(p, self._receiver)
        self._metrics.partition_moves.labels(direction="in").inc(len(partitions))
        log.info(
            "took %d partition(s) in %.0f ms (%d checkpoint(s) from other instances, %d "
            "frame(s) held meanwhile): %s",
            len(partitions),
            (time.monotonic() - started) * 1000.0,
            fetched,
            held,
            ranges(partitions),
        )


def read_release(key: str, payload: bytes) -> tuple[int, str, int] | None:
    """(partition, instance, epoch) of a release announcement, None if it is not one."""
    try:
        partition, instance = keys.parse_released_key(key)
        obj = msgpack.unpackb(payload, raw=False)
        if not isinstance(obj, dict) or obj.get("released") != RELEASE_VERSION:
            return None
        epoch = obj.get("epoch")
    except (WireError, ValueError) as exc:
        log.warning("ignored a release announcement on %s: %s", key[:200], exc)
        return None
    return (partition, instance, epoch) if type(epoch) is int else None


def ranges(partitions: Sequence[int]) -> str:
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

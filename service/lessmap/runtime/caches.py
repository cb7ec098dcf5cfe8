"""Queries of the robots' publication caches: a session's catch-up, a take-over's probe.

Invariants:

1. The callbacks only enqueue: a catch-up's replies and its end go to the robot's shard
   (``RECOVERED``, then one ``CATCHUP_DONE``, the same FIFO, so the end follows its
   replies); a probe's replies go to the receiver, whose next sweep hands them on behind
   the live frames already received (a robot's cache answers after the robot put them).
2. Consolidation is off (every cached sample has the same key) and replies keyed as the
   frames are accepted (they do not match the ``@adv`` selector).
3. A catch-up that cannot be sent (not owned, a closing session) ends at once: the hold is
   released, never left waiting.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import zenoh

from lessmap.runtime.inbound import CATCHUP_DONE, PROBE, RECOVERED, Inbound
from lessmap_schemas import keys

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap.runtime.receiver import Receiver
    from lessmap.runtime.sessions.model import CatchupRequest
    from lessmap.runtime.shard import Shard

log = logging.getLogger(__name__)


class CacheQueries:
    """Sends the queries of the robots' publication caches on one Zenoh session."""

    def __init__(
        self,
        session: zenoh.Session,
        owns: Callable[[str, str], bool],
        *,
        max_payload_bytes: int,
        wait_s: float,
    ) -> None:
        self._session = session
        self._owns = owns
        self._max_payload = max_payload_bytes
        self._wait_s = wait_s

    def request_catchup(self, shard: Shard, request: CatchupRequest) -> None:
        """Ask a robot's publication cache for its newest frames (worker thread, no wait).

        The query goes to the cache queryables of the robot's frames key (``@adv/**`` below
        it, where AdvancedPublishers answer).
        """
        key = keys.frames(request.fleet, request.robot)
        max_payload = self._max_payload
        done = Inbound(0.0, key, request.session.encode(), CATCHUP_DONE)
        if not self._owns(request.fleet, request.robot):
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
            self._session.get(
                f"{key}/@adv/**?_max={request.max_frames}",
                zenoh.handlers.Callback(on_reply, on_end),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                accept_replies=zenoh.ReplyKeyExpr.ANY,
                timeout=self._wait_s,
            )
        except zenoh.ZError as exc:  # a closing session: the hold is released at once
            log.warning("catch-up query of %s failed: %s", key, exc)
            shard.offer(done)

    def probe(self, partition: int, receiver: Receiver) -> None:
        """Ask the robots' caches of a partition just taken for their newest frame each.

        A robot that sent frames while no instance was subscribed to its partition and then
        fell silent would otherwise wait for its next frame. Each cache answers with its
        newest frame (``_max=1``), which the shard applies like a live one only if the table
        does not know it (``SessionTable.is_news``): a session ahead of its checkpoint, or
        unknown, then resumes and catches up as after a gap; a frame already seen is dropped
        uncounted (it was counted when it arrived).
        """
        suffix = f"/frames/{partition}"
        max_payload = self._max_payload

        def on_reply(reply: zenoh.Reply) -> None:  # Zenoh's thread: enqueue only
            sample = reply.ok
            if sample is None or len(sample.payload) > max_payload:
                return
            key = str(sample.key_expr)
            if key.endswith(suffix) and "@" not in key:
                receiver.probe(Inbound(time.monotonic(), key, sample.payload.to_bytes(), PROBE))

        try:
            self._session.get(
                f"{keys.frames_of_partition(partition)}/@adv/**?_max=1",
                zenoh.handlers.Callback(on_reply, lambda: None),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                accept_replies=zenoh.ReplyKeyExpr.ANY,
                timeout=self._wait_s,
            )
        except zenoh.ZError as exc:
            log.warning("probe of the robots' caches of partition %d failed: %s", partition, exc)

"""Follow one fleet on the lessmap bus and log it to Foxglove channels (server, MCAP or both).

Three inputs: the robots' frames (their poses and features: a plain Zenoh subscriber on the
fleet's frames keys, which no SDK call offers, hence Zenoh here), the service's transitions
(an SDK subscription with history) and its session states (an SDK query every
``state_period_s``). Zenoh's and the SDK's threads only queue what arrives; the feed's own
thread updates the model and logs scene updates at most every ``scene_period_s``, only for
robots that changed.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from typing import TYPE_CHECKING

import foxglove
import zenoh
from foxglove.channels import LogChannel, SceneUpdateChannel

from lessmap.viz.model import FleetModel
from lessmap.viz.scene import (
    COVGRAPH_TOPIC,
    SCENE_TOPIC,
    STATE_SCHEMA,
    STATE_TOPIC,
    TRANSITIONS_TOPIC,
    covgraph_entity,
    scene,
    state_table,
    track_entities,
    transition_log,
)
from lessmap_schemas import keys
from lessmap_schemas.codec import decode_inbound
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import Frame, Transition

if TYPE_CHECKING:
    from lessmap_client.connection import Connection
    from lessmap_client.subscription import Subscription

log = logging.getLogger(__name__)


class FleetFeed:
    """Log a fleet to the channels of a Foxglove context.

    Args:
        session: a Zenoh session on the lessmap network (for the frames).
        conn: the SDK connection on it (transitions, states).
        fleet: the fleet to follow.
        context: the Foxglove context whose sinks (server, MCAP writer) get the messages.
        covgraph: a robot whose current submap's CovGraph is also shown, or None.
        scene_period_s: least time between two scene updates of one robot.
        state_period_s: how often the state table is queried and logged.
    """

    def __init__(
        self,
        session: zenoh.Session,
        conn: Connection,
        fleet: str,
        context: foxglove.Context,
        *,
        covgraph: str | None = None,
        scene_period_s: float = 0.5,
        state_period_s: float = 1.0,
    ) -> None:
        self.fleet = keys.validate_name(fleet, "fleet")
        self.covgraph_robot = None if covgraph is None else keys.validate_name(covgraph, "robot")
        self.model = FleetModel(self.fleet)
        self.counts: Counter[str] = Counter()
        self.scene_period_s = scene_period_s
        self.state_period_s = state_period_s
        self._session = session
        self._conn = conn
        self._queue: queue.Queue[tuple[str, bytes] | Transition | None] = queue.Queue(100000)
        self._scene = SceneUpdateChannel(SCENE_TOPIC, context=context)
        self._log = LogChannel(TRANSITIONS_TOPIC, context=context)
        self._state = foxglove.Channel(STATE_TOPIC, schema=STATE_SCHEMA, context=context)
        self._graph = (
            SceneUpdateChannel(COVGRAPH_TOPIC, context=context) if self.covgraph_robot else None
        )
        self._frames: zenoh.Subscriber[None] | None = None
        self._transitions: Subscription[Transition] | None = None
        self._thread = threading.Thread(target=self._run, name="lessmap-viz", daemon=True)
        self._dirty: set[str] = set()

    def start(self) -> FleetFeed:
        """Subscribe and start the feed's thread."""
        self._thread.start()
        key = f"{keys.KEY_PREFIX}/{self.fleet}/*/frames/*"
        self._frames = self._session.declare_subscriber(
            key, zenoh.handlers.Callback(self._on_frame)
        )
        self._transitions = self._conn.subscribe_transitions(self.fleet, handler=self._queue_put)
        log.info("following fleet %s (frames on %s)", self.fleet, key)
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Unsubscribe, log what was queued, stop the thread."""
        if self._frames is not None:
            self._frames.undeclare()
            self._frames = None
        if self._transitions is not None:
            self._transitions.close()
            self._transitions = None
        self._queue.put(None)
        self._thread.join(timeout_s)
        if self.covgraph_robot is not None and self.covgraph_robot not in self.model.tracks:
            log.warning(
                "--covgraph %s: no frame of that robot was seen (robots: %s)",
                self.covgraph_robot,
                ", ".join(sorted(self.model.tracks)) or "none",
            )

    # -- Zenoh's and the SDK's threads: queue only -------------------------------------------

    def _on_frame(self, sample: zenoh.Sample) -> None:
        self._queue_put((str(sample.key_expr), sample.payload.to_bytes()))

    def _queue_put(self, item: tuple[str, bytes] | Transition) -> None:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.counts["dropped: viewer queue full"] += 1

    # -- the feed's thread -------------------------------------------------------------------

    def _run(self) -> None:
        next_scene = next_state = time.monotonic()
        while True:
            try:
                item = self._queue.get(timeout=0.05)
            except queue.Empty:
                pass  # nothing new: the periodic updates below still run
            else:
                if item is None:
                    break
                try:
                    self._apply(item)
                except Exception:  # the view must survive a bad event
                    log.exception("cannot show an event")
            now = time.monotonic()
            if now >= next_scene:
                self._log_scene()
                next_scene = now + self.scene_period_s
            if now >= next_state:
                self._log_state()
                next_state = now + self.state_period_s
        self._log_scene()
        self._log_state()

    def _apply(self, item: tuple[str, bytes] | Transition) -> None:
        if isinstance(item, Transition):
            mark = self.model.on_transition(item)
            if mark is not None:
                log.info(
                    "%s/%s: submap %d -> %d at seq %d",
                    self.fleet,
                    item.robot,
                    mark.closed,
                    mark.opened,
                    mark.boundary_seq,
                )
                self._log.log(transition_log(item.robot, mark))
                self.counts["transitions"] += 1
                self._dirty.add(item.robot)
            return
        key, payload = item
        try:
            robot = key.split("/")[3]
            message = decode_inbound(payload)
        except (IndexError, WireError):
            self.counts["undecodable frames"] += 1
            return
        if isinstance(message, Frame):
            self.model.on_frame(robot, message)
            self.counts["frames"] += 1
            self._dirty.add(robot)

    def _log_scene(self) -> None:
        entities = []
        for robot in sorted(self._dirty):
            entities += track_entities(self.model.tracks[robot])
        if entities:
            self._scene.log(scene(entities))
            self.counts["scene updates"] += 1
        if self._graph is not None and self.covgraph_robot in self._dirty:
            graph = self.model.covgraph(self.covgraph_robot)
            track = self.model.tracks[self.covgraph_robot]
            if graph is not None:
                last = track.points[-1].stamp_s if track.points else 0.0
                self._graph.log(scene([covgraph_entity(self.covgraph_robot, graph, last)]))
                self.counts["covgraph updates"] += 1
        self._dirty.clear()

    def _log_state(self) -> None:
        try:
            states = self._conn.states(self.fleet, timeout_s=1.0)
        except Exception:  # a closing connection: the next period tries again
            log.debug("state query failed", exc_info=True)
            return
        self._state.log(state_table(self.fleet, states))
        self.counts["state tables"] += 1

"""Follow one fleet on the lessmap bus and log it to Foxglove channels (server, MCAP or both).

Three inputs: the robots' frames (their poses and features: a plain Zenoh subscriber on the
fleet's frames keys, which no SDK call offers, hence Zenoh here), the service's transitions
(an SDK subscription with history) and its session states (an SDK query every
``state_period_s``). Zenoh's and the SDK's threads only queue what arrives; the feed's own
thread updates the model and logs scene updates at most every ``scene_period_s``, only for
robots that changed.

Late joiners. Live messages reach only the clients subscribed when they are logged, so a
client that connects (or subscribes) later would see an empty scene and log. The Foxglove
SDK calls a server listener's ``on_subscribe`` after the new subscription is in place;
``LateJoiners`` notes the topic and the client, and the feed's thread re-sends that channel's
current picture: the whole scene, the ``map`` transform, the last state table, the CovGraph,
and the recent transitions (``RECENT_TRANSITIONS_PER_ROBOT`` per robot).

A re-send reaches every client subscribed to the channel: the Python SDK (0.30) cannot log
to one client. ``Channel.log`` takes a ``sink_id`` and each WebSocket client is a sink, but
the ``Client`` its listener receives carries only the server's client id, not the sink id
(Rust's ``Client::sink_id`` is not bound), and the two differ once another sink exists (an
MCAP file of ``view --mcap``). That is harmless for the scene, transform, table and CovGraph,
whose messages replace what a panel shows, but a Log panel appends: so the recent
transitions are re-sent only when every client subscribed to the log is new since the last
re-send (the usual case: one viewer that reconnects). A client that joins while another one
follows the log gets the scene (a label per doorway) and the table (transitions per robot)
but no log history, and the one already following sees no entry twice. Re-sends go only to
the live server's context, never into an MCAP file.

Poses. The trajectories come from the robots' frames keys; a secured site's access control
lets a fleet app (``app.<fleet>``) read the transitions but not the frames, a viewer
(``viewer.<fleet>``, ``lessmap.security.siteconfig``) both. When transitions arrive and no frame has
reached the view ``NO_FRAMES_WARNING_S`` later, the feed says so once.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter, deque
from typing import TYPE_CHECKING, Any

import foxglove
import zenoh
from foxglove.channels import FrameTransformChannel, LogChannel, SceneUpdateChannel
from foxglove.websocket import ServerListener

from lessmap.viz.model import FleetModel
from lessmap.viz.scene import (
    COVGRAPH_TOPIC,
    SCENE_TOPIC,
    STATE_SCHEMA,
    STATE_TOPIC,
    TF_TOPIC,
    TRANSITIONS_TOPIC,
    covgraph_entity,
    doorway_entity,
    doorways,
    fleet_entities,
    map_transform,
    places_of,
    previous_entity,
    scene,
    state_table,
    track_entities,
    transition_log,
)
from lessmap_client.fleet_areas import FleetGraph, FleetParams
from lessmap_schemas import keys
from lessmap_schemas.codec import decode_inbound
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import Frame, Transition

if TYPE_CHECKING:
    from foxglove.messages import Log, SceneEntity, SceneUpdate
    from foxglove.websocket import ChannelView, Client

    from lessmap_client.connection import Connection
    from lessmap_client.subscription import Subscription

log = logging.getLogger(__name__)

#: Transitions re-sent per robot to a client that subscribes late: about what the Log panel
#: of the shipped layout shows, and each robot's last few areas (a sim robot makes 14-18
#: transitions in 600 frames). Older ones stay in the state table's counts and in recordings.
RECENT_TRANSITIONS_PER_ROBOT = 10
#: At most this many in one re-send (the newest): the SDK queues up to 1024 messages per
#: client and drops the oldest beyond that, which must not be the scene sent alongside.
RECENT_TRANSITIONS_MAX = 500
#: How long after the first transition a view with no frame at all says that it cannot read
#: the robots' frames (their poses).
NO_FRAMES_WARNING_S = 5.0


class LateJoiners(ServerListener):
    """A Foxglove server listener that notes which clients subscribe to which topics.

    Called on the SDK's threads: it only records; the feed's thread re-sends.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._following: dict[str, set[int]] = {}  # topic -> ids of the clients subscribed
        self._new: dict[str, set[int]] = {}  # topic -> those subscribed since the last take

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        """Note that a client subscribed to ``channel``."""
        with self._lock:
            self._following.setdefault(channel.topic, set()).add(client.id)
            self._new.setdefault(channel.topic, set()).add(client.id)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        """Note that a client unsubscribed from ``channel`` (or disconnected)."""
        with self._lock:
            self._following.get(channel.topic, set()).discard(client.id)
            self._new.get(channel.topic, set()).discard(client.id)

    def take(self) -> dict[str, bool]:
        """Return the topics subscribed to since the last call.

        Returns:
            For each topic, whether every client subscribed to it is new since the last call,
            i.e. whether a message logged now reaches no client twice.
        """
        with self._lock:
            new, self._new = self._new, {}
            return {
                topic: self._following.get(topic, set()) <= clients
                for topic, clients in new.items()
                if clients
            }


class Channels:
    """The feed's channels in one Foxglove context (the live server's or the MCAP file's).

    Create them before the server starts: a channel created while a client is connected is
    advertised to it a moment before the server accepts subscriptions to it (foxglove-sdk
    0.30 answers "Unknown channel ID" in that window), while the channels that exist when a
    client connects are in the first advertisement.
    """

    def __init__(self, context: foxglove.Context, *, covgraph: bool) -> None:
        self.context = context
        self.scene = SceneUpdateChannel(SCENE_TOPIC, context=context)
        self.log = LogChannel(TRANSITIONS_TOPIC, context=context)
        self.state = foxglove.Channel(STATE_TOPIC, schema=STATE_SCHEMA, context=context)
        self.tf = FrameTransformChannel(TF_TOPIC, context=context)
        self.graph = SceneUpdateChannel(COVGRAPH_TOPIC, context=context) if covgraph else None


class FleetFeed:
    """Log a fleet to the channels of a live server's context, an MCAP file's, or both.

    Args:
        session: a Zenoh session on the lessmap network (for the frames).
        conn: the SDK connection on it (transitions, states).
        fleet: the fleet to follow.
        live: the channels of a Foxglove WebSocket server's context, or None.
        record: the channels of an MCAP writer's context, or None (every message is logged
            to both).
        joiners: the listener the live server was started with: channels clients subscribe
            to get their current picture again, on ``live`` only.
        covgraph: a robot whose current submap's CovGraph is also shown (its channels need
            ``covgraph=True``), or None.
        scene_period_s: least time between two scene updates of one robot.
        state_period_s: how often the state table is queried and logged.
    """

    def __init__(
        self,
        session: zenoh.Session,
        conn: Connection,
        fleet: str,
        *,
        live: Channels | None = None,
        record: Channels | None = None,
        joiners: LateJoiners | None = None,
        covgraph: str | None = None,
        scene_period_s: float = 0.5,
        state_period_s: float = 1.0,
        places_period_s: float | None = None,
    ) -> None:
        if live is None and record is None:
            msg = "a feed needs live channels, record channels or both"
            raise ValueError(msg)
        self.fleet = keys.validate_name(fleet, "fleet")
        self.covgraph_robot = None if covgraph is None else keys.validate_name(covgraph, "robot")
        self.model = FleetModel(self.fleet)
        self.counts: Counter[str] = Counter()
        self.scene_period_s = scene_period_s
        self.state_period_s = state_period_s
        # With global feature ids: each robot's place (fleet area) in the state table, from a
        # fleet_area_graph this often (a query for every robot's graph: less often than states).
        self.places_period_s = places_period_s
        self._places_graph: FleetGraph | None = None
        self._places_due = 0.0
        self._session = session
        self._conn = conn
        self._queue: queue.Queue[tuple[str, bytes] | Transition | None] = queue.Queue(100000)
        self._live = live
        self._sinks = [c for c in (live, record) if c is not None]
        self._joiners = joiners
        self._frames: zenoh.Subscriber[None] | None = None
        self._transitions: Subscription[Transition] | None = None
        self._thread = threading.Thread(target=self._run, name="lessmap-viz", daemon=True)
        self._dirty: set[str] = set()
        self._previous_sent: dict[str, str] = {}  # robot -> session of its dimmed line, as sent
        self._marks_sent = 0  # the model's marks_version the doorways were last sent for
        self._recent: dict[str, deque[tuple[int, Log]]] = {}
        self._logged = 0
        self._state_message: dict[str, Any] | None = None
        self._first_transition_at: float | None = None
        self._warned_no_frames = False

    def start(self) -> FleetFeed:
        """Log the ``map`` transform, subscribe and start the feed's thread."""
        for sink in self._sinks:
            sink.tf.log(map_transform())
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
            if self._joiners is not None:
                for topic, only_new in sorted(self._joiners.take().items()):
                    try:
                        self._resend(topic, only_new=only_new)
                    except Exception:
                        log.exception("cannot re-send %s", topic)
            self._check_frames()
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
            if self._first_transition_at is None:
                self._first_transition_at = time.monotonic()
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
                entry = transition_log(item.robot, mark)
                for sink in self._sinks:
                    sink.log.log(entry)
                self._logged += 1
                recent = self._recent.setdefault(
                    item.robot, deque(maxlen=RECENT_TRANSITIONS_PER_ROBOT)
                )
                recent.append((self._logged, entry))
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
            self.counts["frames"] += 1
            if self.model.on_frame(robot, message) is not None:
                self._dirty.add(robot)

    def _log_scene(self) -> None:
        entities: list[SceneEntity] = []
        for robot in sorted(self._dirty):
            if robot in self.model.tracks:
                entities += self._changed_entities(robot)
        if self.model.marks_version != self._marks_sent:
            entities.append(doorway_entity(doorways(self.model.tracks.values())))
            self._marks_sent = self.model.marks_version
        if entities:
            update = scene(entities)
            for sink in self._sinks:
                sink.scene.log(update)
            self.counts["scene updates"] += 1
        if self.covgraph_robot is not None and self.covgraph_robot in self._dirty:
            graph = self._covgraph()
            if graph is not None:
                for sink in self._sinks:
                    if sink.graph is not None:
                        sink.graph.log(graph)
                self.counts["covgraph updates"] += 1
        self._dirty.clear()

    def _changed_entities(self, robot: str) -> list[SceneEntity]:
        """Return a robot's trajectory, and its previous session's line if not sent yet."""
        entities = track_entities(self.model.tracks[robot])
        left = self.model.previous.get(robot)
        if left is not None and self._previous_sent.get(robot) != left.session:
            entities.append(previous_entity(left))
            self._previous_sent[robot] = left.session
        return entities

    def _covgraph(self) -> SceneUpdate | None:
        robot = self.covgraph_robot
        if robot is None:
            return None
        graph = self.model.covgraph(robot)
        if graph is None:
            return None
        track = self.model.tracks[robot]
        last = track.points[-1].stamp_s if track.points else 0.0
        return scene([covgraph_entity(robot, graph, last)])

    def _log_state(self) -> None:
        try:
            states = self._conn.states(self.fleet, timeout_s=1.0)
        except Exception:  # a closing connection: the next period tries again
            log.debug("state query failed", exc_info=True)
            return
        places = None
        if self.places_period_s is not None:
            graph = self._places_graph
            unplaced = graph is None or any(
                (s.robot, s.current_area) not in graph.area_of for s in states
            )
            if unplaced or time.monotonic() >= self._places_due:
                # Due, or a robot in an area the last graph did not hold: a new robot or area
                # gets its place within a state period, not a places period.
                self._places_due = time.monotonic() + self.places_period_s
                try:
                    graph = self._conn.fleet_area_graph(
                        self.fleet, FleetParams(shared_features=True), timeout_s=1.0
                    )
                except Exception:  # as for states: the next period tries again
                    log.debug("fleet area query failed", exc_info=True)
                else:
                    self._places_graph = graph
                    self.counts["place queries"] += 1
            places = {} if graph is None else places_of(states, graph)
        self._state_message = state_table(self.fleet, states, places)
        for sink in self._sinks:
            sink.state.log(self._state_message)
        self.counts["state tables"] += 1

    def _check_frames(self) -> None:
        """Say once that no frame is readable if transitions came and frames did not."""
        if self._first_transition_at is None or self._warned_no_frames:
            return
        if self.counts["frames"]:
            self._warned_no_frames = True  # frames are readable: nothing to say
        elif time.monotonic() - self._first_transition_at >= NO_FRAMES_WARNING_S:
            self._warned_no_frames = True
            self.counts["no frames readable"] = 1
            log.warning(
                "fleet %s: transitions arrive but no frame reached the view in %g s, so the "
                "trajectories stay empty: this identity cannot read %s/%s/*/frames/* (on a "
                "secured site app.%s may not; connect as viewer.%s: --zenoh-config "
                "zenoh-viewer-%s-mtls.json5 from lessmap certs)",
                self.fleet,
                NO_FRAMES_WARNING_S,
                keys.KEY_PREFIX,
                self.fleet,
                self.fleet,
                self.fleet,
                self.fleet,
            )

    def _resend(self, topic: str, *, only_new: bool) -> None:
        """Log a channel's current picture again, to the live server only.

        Args:
            topic: the channel a client subscribed to.
            only_new: no client subscribed to it has had its messages so far (a Log panel
                would show a re-sent entry twice).
        """
        live = self._live
        if live is None:
            return
        if topic == SCENE_TOPIC:
            live.scene.log(scene(fleet_entities(self.model)))
            self.counts["scene re-sends"] += 1
        elif topic == TF_TOPIC:
            live.tf.log(map_transform())
        elif topic == STATE_TOPIC and self._state_message is not None:
            live.state.log(self._state_message)
        elif topic == COVGRAPH_TOPIC and live.graph is not None:
            graph = self._covgraph()
            if graph is not None:
                live.graph.log(graph)
        elif topic == TRANSITIONS_TOPIC and not only_new:
            self.counts["log re-sends withheld"] += 1
        elif topic == TRANSITIONS_TOPIC:
            entries = sorted(
                (item for recent in self._recent.values() for item in recent),
                key=lambda item: item[0],
            )[-RECENT_TRANSITIONS_MAX:]
            for _, entry in entries:
                live.log.log(entry)
            self.counts["transitions re-sent"] += len(entries)
        log.debug("->> %s again (a client subscribed)", topic)

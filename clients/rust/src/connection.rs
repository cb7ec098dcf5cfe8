//! One Zenoh session to a lessmap network, from which robots, subscriptions and queries are
//! declared (the shape of the Python SDK's `lessmap_client.connect()`).
//!
//! Invariants of this file:
//!
//! * Queries ask every queryable and keep every reply (target `ALL`, consolidation `NONE`):
//!   during a hand-over an old and a new owner answer on the same key, and Zenoh's default
//!   consolidation would keep one of them, not necessarily the current one.
//! * Of several `SessionState` replies for one robot, the highest epoch (then the most
//!   `frames_applied`) is current; of several `AreaGraph` replies, the highest epoch (then
//!   the most frames over its areas).
//! * A reply that does not decode is skipped and logged, never returned.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::time::{Duration, Instant};

use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::{Session, Wait};

use crate::codec::{decode, WireError};
use crate::fleet_areas::{fleet_graph, FleetGraph, FleetMergeError, FleetParams};
use crate::messages::{AreaGraph, Health, Message, SessionState, Submap, Transition};
use crate::names::{keys, owner_and_standby, PARTITIONS};
use crate::robot::{RobotOptions, RobotPublisher};
use crate::subscription::Subscription;

/// The embedded router of `lessmap serve` with no options.
pub const DEFAULT_ENDPOINT: &str = "tcp/127.0.0.1:7447";
/// Recent transitions per robot recovered on joining by default.
pub const DEFAULT_HISTORY: usize = 64;

/// What can go wrong on the client side.
#[derive(Debug)]
pub enum ClientError {
    /// A name, a limit or a payload broke the contract (nothing was sent).
    Wire(WireError),
    /// Zenoh failed (config, session, declaration, put).
    Zenoh(zenoh::Error),
    /// No router answered within the timeout.
    Connect(String),
    /// The service closed the session and no new one may be started.
    SessionClosed(String),
    /// The object was already closed.
    Closed,
    /// The robots' area graphs could not be merged into the fleet's.
    FleetMerge(FleetMergeError),
}

impl fmt::Display for ClientError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ClientError::Wire(err) => write!(f, "{err}"),
            ClientError::Zenoh(err) => write!(f, "zenoh: {err}"),
            ClientError::Connect(msg) | ClientError::SessionClosed(msg) => f.write_str(msg),
            ClientError::Closed => f.write_str("already closed"),
            ClientError::FleetMerge(err) => write!(f, "{err}"),
        }
    }
}

impl std::error::Error for ClientError {}

impl From<WireError> for ClientError {
    fn from(err: WireError) -> Self {
        ClientError::Wire(err)
    }
}

impl From<zenoh::Error> for ClientError {
    fn from(err: zenoh::Error) -> Self {
        ClientError::Zenoh(err)
    }
}

/// A Zenoh config for a lessmap client: `mode`, explicit endpoints, no multicast scouting.
pub fn client_config(endpoints: &[&str], mode: &str) -> Result<zenoh::Config, ClientError> {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", &json_string(mode))?;
    if !endpoints.is_empty() {
        let list: Vec<String> = endpoints.iter().map(|e| json_string(e)).collect();
        config.insert_json5("connect/endpoints", &format!("[{}]", list.join(",")))?;
    }
    // Explicit endpoints: scouting would only find unrelated peers on the LAN.
    config.insert_json5("scouting/multicast/enabled", "false")?;
    // The AdvancedPublisher's cache orders samples by timestamp; only routers stamp by default.
    config.insert_json5("timestamping/enabled", "true")?;
    Ok(config)
}

/// A JSON string literal.
fn json_string(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 2);
    out.push('"');
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => out.push_str(&format!("\\u{:04x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// The owner and the standby of a partition, `None` where no instance is alive.
pub type OwnerAndStandby = (Option<String>, Option<String>);

/// An open connection to a lessmap network.
///
/// Closing it (or dropping it) closes the Zenoh session it opened; close robots and
/// subscriptions first, so their `SessionEnd`s go out.
pub struct Connection {
    session: Session,
    owned: bool,
}

impl Connection {
    /// Connect to `endpoints` in client mode, retrying until a router answers.
    ///
    /// A client-mode session fails at once when no router answers yet; retrying until
    /// `timeout` lets a client start next to the service without racing it.
    pub fn connect(endpoints: &[&str], timeout: Duration) -> Result<Connection, ClientError> {
        Connection::connect_with(client_config(endpoints, "client")?, timeout)
    }

    /// Connect with a Zenoh config of your own (TLS, credentials, ...), retrying until `timeout`.
    pub fn connect_with(
        config: zenoh::Config,
        timeout: Duration,
    ) -> Result<Connection, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            match zenoh::open(config.clone()).wait() {
                Ok(session) => {
                    return Ok(Connection {
                        session,
                        owned: true,
                    })
                }
                Err(err) if Instant::now() >= deadline => {
                    return Err(ClientError::Connect(format!(
                        "no Zenoh router reachable within {timeout:?} (is `lessmap serve` running?): {err}"
                    )))
                }
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    }

    /// Wrap a Zenoh session you own; closing the connection leaves it open.
    pub fn from_session(session: Session) -> Connection {
        Connection {
            session,
            owned: false,
        }
    }

    /// The Zenoh session under the connection.
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Declare a robot publisher with the default options (a fresh session id, a cache of
    /// 1000 frames, a new session by itself when the service closes the current one).
    pub fn robot(&self, fleet: &str, robot: &str) -> Result<RobotPublisher, ClientError> {
        RobotPublisher::new(self.session.clone(), fleet, robot, RobotOptions::default())
    }

    /// Declare a robot publisher with options.
    pub fn robot_with(
        &self,
        fleet: &str,
        robot: &str,
        options: RobotOptions,
    ) -> Result<RobotPublisher, ClientError> {
        RobotPublisher::new(self.session.clone(), fleet, robot, options)
    }

    /// Follow the transitions of `fleet`/`robot` (`"*"` for any).
    ///
    /// `history`: recover up to this many recent transitions per robot on joining (`None`:
    /// live only). Transitions lost in transit are fetched from the service's cache either way.
    pub fn subscribe_transitions(
        &self,
        fleet: &str,
        robot: &str,
        history: Option<usize>,
    ) -> Result<Subscription<Transition>, ClientError> {
        let key = keys::transitions(fleet, robot)?;
        Subscription::advanced(
            &self.session,
            key,
            history,
            crate::subscription::DEFAULT_MAXSIZE,
        )
    }

    /// Follow the errors the service reports about `fleet`/`robot` (live only).
    pub fn subscribe_errors(
        &self,
        fleet: &str,
        robot: &str,
    ) -> Result<Subscription<crate::messages::Error>, ClientError> {
        let key = keys::errors(fleet, robot)?;
        Subscription::plain(&self.session, key, crate::subscription::DEFAULT_MAXSIZE)
    }

    /// The robot's session state (open session, else the last closed one), or `None`.
    pub fn state(
        &self,
        fleet: &str,
        robot: &str,
        timeout: Duration,
    ) -> Result<Option<SessionState>, ClientError> {
        Ok(self.states(fleet, robot, timeout)?.into_iter().next())
    }

    /// One state per robot matching `fleet`/`robot` (`"*"` for any), by fleet and robot name.
    pub fn states(
        &self,
        fleet: &str,
        robot: &str,
        timeout: Duration,
    ) -> Result<Vec<SessionState>, ClientError> {
        let found = get_all::<SessionState>(&self.session, &keys::state(fleet, robot)?, timeout)?;
        Ok(current_states(found))
    }

    /// One submap of the robot's session, or `None`.
    pub fn submap(
        &self,
        fleet: &str,
        robot: &str,
        submap_id: u64,
        timeout: Duration,
    ) -> Result<Option<Submap>, ClientError> {
        let key = keys::submap(fleet, robot, submap_id)?;
        Ok(get_all::<Submap>(&self.session, &key, timeout)?
            .into_iter()
            .next())
    }

    /// Every submap of the robot's session, by id.
    pub fn submaps(
        &self,
        fleet: &str,
        robot: &str,
        timeout: Duration,
    ) -> Result<Vec<Submap>, ClientError> {
        let key = keys::submaps(fleet, robot)?;
        let mut by_id = BTreeMap::new();
        for submap in get_all::<Submap>(&self.session, &key, timeout)? {
            by_id.entry(submap.summary.id).or_insert(submap);
        }
        Ok(by_id.into_values().collect())
    }

    /// The areas of the robot's current session and the passages between them, or `None`.
    ///
    /// Under the `paper` method every submap is an area of its own; under `areas` a revisited
    /// area keeps its id.
    pub fn area_graph(
        &self,
        fleet: &str,
        robot: &str,
        timeout: Duration,
    ) -> Result<Option<AreaGraph>, ClientError> {
        Ok(self.area_graphs(fleet, robot, timeout)?.into_iter().next())
    }

    /// One area graph per robot matching `fleet`/`robot` (`"*"` for any), by fleet and robot
    /// name.
    pub fn area_graphs(
        &self,
        fleet: &str,
        robot: &str,
        timeout: Duration,
    ) -> Result<Vec<AreaGraph>, ClientError> {
        let found = get_all::<AreaGraph>(&self.session, &keys::areas(fleet, robot)?, timeout)?;
        Ok(current_area_graphs(found))
    }

    /// The places of one fleet: every robot's area graph (one query for the fleet, wherever
    /// each robot's session lives) merged by [`fleet_graph`]. With
    /// [`FleetParams::shared`] (global feature ids) robots that have been in the same place
    /// share its fleet area; fleet ids name this answer's areas, [`FleetGraph::key_of`] names
    /// them across answers.
    pub fn fleet_area_graph(
        &self,
        fleet: &str,
        params: &FleetParams,
        timeout: Duration,
    ) -> Result<FleetGraph, ClientError> {
        if fleet.contains('*') {
            return Err(ClientError::FleetMerge(FleetMergeError::SeveralFleets(
                vec![fleet.to_owned()],
            )));
        }
        let graphs = self.area_graphs(fleet, "*", timeout)?;
        fleet_graph(&graphs, params).map_err(ClientError::FleetMerge)
    }

    /// The `Health` of every live instance that answers.
    pub fn health(&self, timeout: Duration) -> Result<Vec<Health>, ClientError> {
        get_all::<Health>(&self.session, &keys::health("*")?, timeout)
    }

    /// Sorted names of the live service instances (their liveliness tokens).
    pub fn instances(&self, timeout: Duration) -> Result<Vec<String>, ClientError> {
        instances(&self.session, timeout)
    }

    /// `(owner, standby)` of every partition, ranked over the live instances.
    pub fn coverage(&self, timeout: Duration) -> Result<Vec<OwnerAndStandby>, ClientError> {
        let live = self.instances(timeout)?;
        Ok((0..PARTITIONS)
            .map(|p| owner_and_standby(p, &live))
            .collect())
    }

    /// Wait until a service instance is alive (then every partition has an owner).
    pub fn wait_for_service(&self, timeout: Duration) -> Result<bool, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let ask = left.clamp(Duration::from_millis(100), Duration::from_secs(1));
            if !self.instances(ask)?.is_empty() {
                return Ok(true);
            }
            if Instant::now() >= deadline {
                return Ok(false);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Close the Zenoh session if the connection opened it.
    pub fn close(mut self) -> Result<(), ClientError> {
        self.shut()
    }

    fn shut(&mut self) -> Result<(), ClientError> {
        if self.owned && !self.session.is_closed() {
            self.owned = false;
            self.session.close().wait()?;
        }
        Ok(())
    }
}

impl Drop for Connection {
    fn drop(&mut self) {
        let _ = self.shut();
    }
}

/// Query `key`, asking everybody, and decode every reply as `M` (undecodable ones skipped).
pub(crate) fn get_all<M: Message>(
    session: &Session,
    key: &str,
    timeout: Duration,
) -> Result<Vec<M>, ClientError> {
    let replies = session
        .get(key)
        .target(QueryTarget::All)
        .consolidation(ConsolidationMode::None)
        .timeout(timeout)
        .wait()?;
    let mut found = Vec::new();
    while let Ok(reply) = replies.recv() {
        let Ok(sample) = reply.result() else { continue };
        match decode::<M>(&sample.payload().to_bytes()) {
            Ok(message) => found.push(message),
            Err(err) => tracing::warn!(
                "skipped an undecodable reply on {}: {err}",
                sample.key_expr()
            ),
        }
    }
    Ok(found)
}

pub(crate) fn instances(session: &Session, timeout: Duration) -> Result<Vec<String>, ClientError> {
    let replies = session
        .liveliness()
        .get(keys::instances())
        .timeout(timeout)
        .wait()?;
    let mut names = BTreeSet::new();
    while let Ok(reply) = replies.recv() {
        if let Ok(sample) = reply.result() {
            if let Some(name) = sample.key_expr().as_str().rsplit('/').next() {
                names.insert(name.to_owned());
            }
        }
    }
    Ok(names.into_iter().collect())
}

/// Keep one state per robot: the highest epoch, then the most `frames_applied`.
pub fn current_states(states: Vec<SessionState>) -> Vec<SessionState> {
    let mut best: BTreeMap<(String, String), SessionState> = BTreeMap::new();
    for state in states {
        let robot = (state.fleet.clone(), state.robot.clone());
        match best.get(&robot) {
            Some(kept)
                if (kept.epoch, kept.frames_applied) >= (state.epoch, state.frames_applied) => {}
            _ => {
                best.insert(robot, state);
            }
        }
    }
    best.into_values().collect()
}

/// Keep one area graph per robot: the highest epoch, then the most frames over its areas
/// ([`AreaGraph::total_frames`]); by fleet and robot name.
pub fn current_area_graphs(graphs: Vec<AreaGraph>) -> Vec<AreaGraph> {
    let mut best: BTreeMap<(String, String), AreaGraph> = BTreeMap::new();
    for graph in graphs {
        let robot = (graph.fleet.clone(), graph.robot.clone());
        match best.get(&robot) {
            Some(kept)
                if (kept.epoch, kept.total_frames()) >= (graph.epoch, graph.total_frames()) => {}
            _ => {
                best.insert(robot, graph);
            }
        }
    }
    best.into_values().collect()
}

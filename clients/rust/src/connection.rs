//! One Zenoh session to a lessmap network, from which robots, subscriptions and queries are
//! declared (the shape of the Python SDK's `lessmap_client.connect()`).
//!
//! The queries themselves are in [`crate::query`]; the methods here name them for users.

use std::time::{Duration, Instant};

use zenoh::{Session, Wait};

pub use crate::error::ClientError;
use crate::fleet_areas::{FleetGraph, FleetParams};
use crate::messages::{AreaGraph, Error, Health, SessionState, Submap, Transition};
use crate::names::keys;
use crate::query;
// Their old home: `connection::current_states` and the rest still resolve.
pub use crate::query::{current_area_graphs, current_states, OwnerAndStandby};
use crate::robot::{RobotOptions, RobotPublisher};
use crate::subscription::{Subscription, DEFAULT_MAXSIZE};

/// The embedded router of `lessmap serve` with no options.
pub const DEFAULT_ENDPOINT: &str = "tcp/127.0.0.1:7447";
/// Recent transitions per robot recovered on joining by default.
pub const DEFAULT_HISTORY: usize = 64;

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
        Subscription::advanced(&self.session, key, history, DEFAULT_MAXSIZE)
    }

    /// Follow the errors the service reports about `fleet`/`robot` (live only).
    pub fn subscribe_errors(
        &self,
        fleet: &str,
        robot: &str,
    ) -> Result<Subscription<Error>, ClientError> {
        let key = keys::errors(fleet, robot)?;
        Subscription::plain(&self.session, key, DEFAULT_MAXSIZE)
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
        query::states(&self.session, fleet, robot, timeout)
    }

    /// One submap of the robot's session, or `None`.
    pub fn submap(
        &self,
        fleet: &str,
        robot: &str,
        submap_id: u64,
        timeout: Duration,
    ) -> Result<Option<Submap>, ClientError> {
        query::submap(&self.session, fleet, robot, submap_id, timeout)
    }

    /// Every submap of the robot's session, by id.
    pub fn submaps(
        &self,
        fleet: &str,
        robot: &str,
        timeout: Duration,
    ) -> Result<Vec<Submap>, ClientError> {
        query::submaps(&self.session, fleet, robot, timeout)
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
        query::area_graphs(&self.session, fleet, robot, timeout)
    }

    /// The places of one fleet: every robot's area graph (one query for the fleet, wherever
    /// each robot's session lives) merged by [`fleet_graph`](crate::fleet_graph). With
    /// [`FleetParams::shared`] (global feature ids) robots that have been in the same place
    /// share its fleet area; fleet ids name this answer's areas, [`FleetGraph::key_of`] names
    /// them across answers.
    pub fn fleet_area_graph(
        &self,
        fleet: &str,
        params: &FleetParams,
        timeout: Duration,
    ) -> Result<FleetGraph, ClientError> {
        query::fleet_area_graph(&self.session, fleet, params, timeout)
    }

    /// The `Health` of every live instance that answers.
    pub fn health(&self, timeout: Duration) -> Result<Vec<Health>, ClientError> {
        query::health(&self.session, timeout)
    }

    /// Sorted names of the live service instances (their liveliness tokens).
    pub fn instances(&self, timeout: Duration) -> Result<Vec<String>, ClientError> {
        query::instances(&self.session, timeout)
    }

    /// `(owner, standby)` of every partition, ranked over the live instances.
    pub fn coverage(&self, timeout: Duration) -> Result<Vec<OwnerAndStandby>, ClientError> {
        query::coverage(&self.session, timeout)
    }

    /// Wait until a service instance is alive (then every partition has an owner).
    pub fn wait_for_service(&self, timeout: Duration) -> Result<bool, ClientError> {
        query::wait_for_service(&self.session, timeout)
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

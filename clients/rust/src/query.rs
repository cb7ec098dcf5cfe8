//! Queries of the service's state: robots' session states, submaps and area graphs, the
//! instances' health and liveliness. [`crate::Connection`]'s query methods, the robot
//! publisher's, its follower and the wait for session ends all ask through these functions.
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
use std::time::{Duration, Instant};

use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::{Session, Wait};

use crate::codec::decode;
use crate::error::{ClientError, FleetMergeError};
use crate::fleet_areas::{fleet_graph, FleetGraph, FleetParams};
use crate::messages::{AreaGraph, Health, Message, SessionState, Submap};
use crate::names::{keys, owner_and_standby, PARTITIONS};

/// The owner and the standby of a partition, `None` where no instance is alive.
pub type OwnerAndStandby = (Option<String>, Option<String>);

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

/// Sorted names of the live service instances (their liveliness tokens).
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

/// One current state per robot matching `fleet`/`robot`, by fleet and robot name.
pub(crate) fn states(
    session: &Session,
    fleet: &str,
    robot: &str,
    timeout: Duration,
) -> Result<Vec<SessionState>, ClientError> {
    let found = get_all::<SessionState>(session, &keys::state(fleet, robot)?, timeout)?;
    Ok(current_states(found))
}

/// One current area graph per robot matching `fleet`/`robot`, by fleet and robot name.
pub(crate) fn area_graphs(
    session: &Session,
    fleet: &str,
    robot: &str,
    timeout: Duration,
) -> Result<Vec<AreaGraph>, ClientError> {
    let found = get_all::<AreaGraph>(session, &keys::areas(fleet, robot)?, timeout)?;
    Ok(current_area_graphs(found))
}

/// One submap of the robot's session, or `None`.
pub(crate) fn submap(
    session: &Session,
    fleet: &str,
    robot: &str,
    submap_id: u64,
    timeout: Duration,
) -> Result<Option<Submap>, ClientError> {
    let key = keys::submap(fleet, robot, submap_id)?;
    Ok(get_all::<Submap>(session, &key, timeout)?
        .into_iter()
        .next())
}

/// Every submap of the robot's session, by id (one of each id when several instances answer).
pub(crate) fn submaps(
    session: &Session,
    fleet: &str,
    robot: &str,
    timeout: Duration,
) -> Result<Vec<Submap>, ClientError> {
    let key = keys::submaps(fleet, robot)?;
    let mut by_id = BTreeMap::new();
    for submap in get_all::<Submap>(session, &key, timeout)? {
        by_id.entry(submap.summary.id).or_insert(submap);
    }
    Ok(by_id.into_values().collect())
}

/// The area graphs of one fleet's robots (one wildcard query) merged by [`fleet_graph`].
pub(crate) fn fleet_area_graph(
    session: &Session,
    fleet: &str,
    params: &FleetParams,
    timeout: Duration,
) -> Result<FleetGraph, ClientError> {
    if fleet.contains('*') {
        return Err(ClientError::FleetMerge(FleetMergeError::SeveralFleets(
            vec![fleet.to_owned()],
        )));
    }
    let graphs = area_graphs(session, fleet, "*", timeout)?;
    fleet_graph(&graphs, params).map_err(ClientError::FleetMerge)
}

/// The `Health` of every live instance that answers.
pub(crate) fn health(session: &Session, timeout: Duration) -> Result<Vec<Health>, ClientError> {
    get_all::<Health>(session, &keys::health("*")?, timeout)
}

/// Whether instance `owner` lists `partition` among those it owns in its `Health`. A new owner
/// takes its partitions a moment after its token appears; an owner that does not answer is
/// taken at its token (true).
pub(crate) fn owner_serves(
    session: &Session,
    owner: &str,
    partition: u16,
    timeout: Duration,
) -> Result<bool, ClientError> {
    let replies = get_all::<Health>(session, &keys::health(owner)?, timeout)?;
    if replies.is_empty() {
        return Ok(true);
    }
    Ok(replies
        .iter()
        .any(|h| h.instance == owner && h.partitions.contains(&partition)))
}

/// `(owner, standby)` of every partition, ranked over the live instances.
pub(crate) fn coverage(
    session: &Session,
    timeout: Duration,
) -> Result<Vec<OwnerAndStandby>, ClientError> {
    let live = instances(session, timeout)?;
    Ok((0..PARTITIONS)
        .map(|p| owner_and_standby(p, &live))
        .collect())
}

/// Poll the instances' tokens until one is alive; `false` after `timeout`.
pub(crate) fn wait_for_service(session: &Session, timeout: Duration) -> Result<bool, ClientError> {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let ask = left.clamp(Duration::from_millis(100), Duration::from_secs(1));
        if !instances(session, ask)?.is_empty() {
            return Ok(true);
        }
        if Instant::now() >= deadline {
            return Ok(false);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
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

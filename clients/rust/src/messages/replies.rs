//! The replies of the service's queryables (contract section 5): a robot's `SessionState`,
//! `Submap`s and `AreaGraph`, an instance's `Health`. The invariants of `messages.rs` hold.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{Message, SubmapSummary};
use crate::checks::{
    check, count, each, ensure, feature_limit, features, invalid, non_negative, partition,
    positive, seq, seq_span, MAX_FEATURE_ID,
};
use crate::error::WireError;
use crate::wire_serde::{nested, nested_list, nullable};

/// Segmentation method of a session (a service setting, contract section 6a).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    /// LESS-mapping as published: every submap is an area of its own.
    Paper,
    /// Proposed area changes are confirmed on more evidence, and a robot coming back to an
    /// area it mapped gets that area's id again.
    Areas,
}

impl Method {
    /// The method as written on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Paper => "paper",
            Method::Areas => "areas",
        }
    }
}

impl Serialize for Method {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for Method {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        match String::deserialize(deserializer)?.as_str() {
            "paper" => Ok(Method::Paper),
            "areas" => Ok(Method::Areas),
            other => Err(D::Error::custom(format!("unknown method {other:?}"))),
        }
    }
}

/// Counters and submaps of a robot's current session (reply on the `state` key).
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionState {
    /// Fleet of the robot.
    pub fleet: String,
    /// The robot.
    pub robot: String,
    /// The robot's current (latest) session.
    pub session: String,
    /// First seq of the history the service holds (0 when nothing was lost).
    pub incarnation: u64,
    /// Service instance holding it.
    pub instance: String,
    /// Ownership epoch of the robot's partition at that instance.
    pub epoch: u64,
    /// `false` once a `SessionEnd` (or a newer session) closed it.
    pub open: bool,
    /// Last frame applied; `None` before the first.
    #[serde(deserialize_with = "nullable")]
    pub last_seq: Option<u64>,
    /// Frames applied to the CovGraph, each once, in seq order.
    pub frames_applied: u64,
    /// Frames ignored as `DUPLICATE_SEQ`.
    pub frames_duplicate: u64,
    /// Seqs skipped by a gap and never received.
    pub frames_missing: u64,
    /// Other frames received but not applied.
    pub frames_rejected: u64,
    /// Transitions published for this session.
    pub transitions: u64,
    /// Segmentation method of the session.
    pub method: Method,
    /// The area the robot is in (an [`AreaGraph`] node id).
    pub current_area: u64,
    /// The submap the robot is in.
    #[serde(deserialize_with = "nested")]
    pub current_submap: SubmapSummary,
    /// Submaps left behind, oldest first.
    #[serde(deserialize_with = "nested_list")]
    pub closed_submaps: Vec<SubmapSummary>,
    /// Nodes of the CovGraph.
    pub nodes: u64,
    /// Edges of the CovGraph.
    pub edges: u64,
}

impl Message for SessionState {
    const TYPE: &'static str = "SessionState";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names: fleet, robot, session, instance);
        check!(self, "SessionState", positive: epoch);
        check!(self, "SessionState", seq?: last_seq);
        check!(self, "SessionState", seq: incarnation);
        check!(
            self,
            "SessionState",
            count: frames_applied,
            frames_duplicate,
            frames_missing,
            frames_rejected,
            transitions,
            current_area
        );
        self.current_submap
            .validate("SessionState.current_submap")?;
        each(
            &self.closed_submaps,
            "SessionState.closed_submaps",
            SubmapSummary::validate,
        )?;
        check!(self, "SessionState", count: nodes, edges);
        Ok(())
    }
}
wire_map!(
    SessionState,
    [
        fleet,
        robot,
        session,
        incarnation,
        instance,
        epoch,
        open,
        last_seq,
        frames_applied,
        frames_duplicate,
        frames_missing,
        frames_rejected,
        transitions,
        method,
        current_area,
        current_submap,
        closed_submaps,
        nodes,
        edges,
    ]
);

/// One submap of a robot's session (reply on the `submaps/<id>` key).
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Submap {
    /// Fleet of the robot.
    pub fleet: String,
    /// The robot.
    pub robot: String,
    /// Session the submap belongs to.
    pub session: String,
    /// Frames and features of the submap.
    #[serde(deserialize_with = "nested")]
    pub summary: SubmapSummary,
    /// `true` for the submap the robot is in (it still grows).
    pub open: bool,
}

impl Message for Submap {
    const TYPE: &'static str = "Submap";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names: fleet, robot, session);
        self.summary.validate("Submap.summary")
    }
}
wire_map!(Submap, [fleet, robot, session, summary, open]);

/// One area of a robot's session: a node of its [`AreaGraph`] (nested only).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AreaNode {
    /// Area id within the session, from 0 in order of opening; a merged id is not reused.
    pub id: u64,
    /// Frames the robot spent in the area over all its visits (empty frames too).
    pub frames: u64,
    /// Separate stays in the area, at least 1.
    pub visits: u64,
    /// First frame in the area.
    pub first_seq: u64,
    /// Last frame in the area so far; `first_seq <= last_seq`.
    pub last_seq: u64,
    /// Distinct feature IDs of the area, ascending.
    pub features: Vec<u64>,
}

impl AreaNode {
    fn validate(&self, at: &str) -> Result<(), WireError> {
        check!(self, at, count: id, frames);
        check!(self, at, positive: visits);
        check!(self, at, seq: first_seq, last_seq);
        features(&self.features, &format!("{at}.features"))?;
        seq_span(self.first_seq, self.last_seq, at)
    }
}

/// The robot's passages between two areas `a < b`: an edge of its [`AreaGraph`] (nested only).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Passage {
    /// The lower area id.
    pub a: u64,
    /// The higher area id; `a < b`.
    pub b: u64,
    /// Passages from `a` to `b`.
    pub a_to_b: u64,
    /// Passages from `b` to `a`; `a_to_b + b_to_a >= 1`.
    pub b_to_a: u64,
    /// `(feature ID, passages that reported it)`: the features most often reported on this
    /// boundary, most frequent first (ties: smaller id); at most 16 (a service setting), and a
    /// trimmed count is a lower bound. Each pair is a 2-item msgpack array.
    pub boundary_features: Vec<(u64, u64)>,
}

impl Passage {
    fn validate(&self, at: &str) -> Result<(), WireError> {
        check!(self, at, count: a, b, a_to_b, b_to_a);
        for (index, (id, reports)) in self.boundary_features.iter().enumerate() {
            let field = format!("{at}.boundary_features.{index}");
            if *id > MAX_FEATURE_ID {
                return Err(feature_limit(*id, &field));
            }
            count(*reports, &field)?;
        }
        ensure(self.a < self.b, || {
            format!("{at}: a={} must be below b={}", self.a, self.b)
        })?;
        // Both are at most 2**53-1 here: the sum cannot overflow.
        ensure(self.a_to_b + self.b_to_a > 0, || {
            format!("{at}: passage {}-{} counts no passage", self.a, self.b)
        })
    }
}

/// The areas of a robot's current session and the passages between them (reply on the
/// `areas` key).
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AreaGraph {
    /// Fleet of the robot.
    pub fleet: String,
    /// The robot.
    pub robot: String,
    /// The session the areas belong to (the robot's current one, open or closed).
    pub session: String,
    /// Service instance holding the session.
    pub instance: String,
    /// Ownership epoch of the robot's partition at that instance.
    pub epoch: u64,
    /// Segmentation method of the session; under `Paper` every submap is its own area.
    pub method: Method,
    /// The areas the robot has been in, by strictly ascending id; empty before the first frame.
    #[serde(deserialize_with = "nested_list")]
    pub areas: Vec<AreaNode>,
    /// One per pair of areas the robot passed between, by strictly ascending `(a, b)`; every
    /// `a` and `b` is the id of a listed area.
    #[serde(deserialize_with = "nested_list")]
    pub passages: Vec<Passage>,
}

impl AreaGraph {
    /// Frames over every area: of two replies with one epoch, the one with more is current.
    pub fn total_frames(&self) -> u64 {
        self.areas
            .iter()
            .fold(0u64, |sum, area| sum.saturating_add(area.frames))
    }

    /// The area with id `id`, if listed (a binary search: a decoded graph lists its areas by
    /// ascending id).
    pub fn area(&self, id: u64) -> Option<&AreaNode> {
        self.areas
            .binary_search_by_key(&id, |area| area.id)
            .ok()
            .map(|index| &self.areas[index])
    }
}

impl Message for AreaGraph {
    const TYPE: &'static str = "AreaGraph";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names: fleet, robot, session, instance);
        check!(self, "AreaGraph", positive: epoch);
        each(&self.areas, "AreaGraph.areas", AreaNode::validate)?;
        each(&self.passages, "AreaGraph.passages", Passage::validate)?;
        ensure(
            self.areas.windows(2).all(|pair| pair[0].id < pair[1].id),
            || "AreaGraph: areas must be listed by strictly ascending id".into(),
        )?;
        // The ids are sorted now, so `area` may search them.
        if let Some(passage) = self
            .passages
            .iter()
            .find(|p| self.area(p.a).is_none() || self.area(p.b).is_none())
        {
            return Err(invalid(format!(
                "AreaGraph: passage {}-{} names an area that is not listed",
                passage.a, passage.b
            )));
        }
        ensure(
            self.passages
                .windows(2)
                .all(|pair| (pair[0].a, pair[0].b) < (pair[1].a, pair[1].b)),
            || "AreaGraph: passages must be listed by strictly ascending (a, b)".into(),
        )
    }
}
wire_map!(
    AreaGraph,
    [fleet, robot, session, instance, epoch, method, areas, passages]
);

/// Liveness figures of one service instance (reply on the `@/health/<instance>` key).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Health {
    /// The instance reporting.
    pub instance: String,
    /// Service software version, 1 to 64 characters.
    pub version: String,
    /// Sessions held in memory.
    pub sessions: u64,
    /// Seconds since the instance started.
    pub uptime_s: f64,
    /// Frames applied over all sessions since start.
    pub frames_applied: u64,
    /// Partitions this instance owns, ascending.
    pub partitions: Vec<u16>,
    /// Partitions this instance is the standby of, ascending.
    pub standby: Vec<u16>,
    /// Messages received and not yet handled.
    pub queue_depth: u64,
    /// Age of the oldest message not yet handled, seconds.
    pub lag_s: f64,
}

impl Message for Health {
    const TYPE: &'static str = "Health";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names: instance);
        let chars = self.version.chars().count();
        ensure((1..=64).contains(&chars), || {
            format!("Health.version has {chars} characters, not 1..64")
        })?;
        check!(self, "Health", count: sessions);
        check!(self, "Health", non_negative: uptime_s);
        check!(self, "Health", count: frames_applied);
        for p in self.partitions.iter().chain(&self.standby) {
            partition(*p, "Health.partitions")?;
        }
        check!(self, "Health", count: queue_depth);
        check!(self, "Health", non_negative: lag_s);
        Ok(())
    }
}
wire_map!(
    Health,
    [
        instance,
        version,
        sessions,
        uptime_s,
        frames_applied,
        partitions,
        standby,
        queue_depth,
        lag_s
    ]
);

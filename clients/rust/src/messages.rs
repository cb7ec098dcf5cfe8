//! The messages of the wire contract v3 (section 5), field for field.
//!
//! Invariants of this file:
//!
//! * `Serialize` writes the wire map: `type`, `v`, then every field in the contract's order
//!   (the canonical form; `nil` for `None`, never an omitted key).
//! * `Deserialize` reads the fields only: [`crate::codec`] checks `type` and `v` first and
//!   hands the rest over. Unknown fields are rejected, and so is a missing field even when its
//!   value may be `nil` (only `Frame.pose` may be omitted).
//! * Serde checks types; `validate` checks ranges, names and consistency, with the code the
//!   contract gives each failure.

use serde::de::{DeserializeOwned, Error as _};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::checks::{
    check, count, each, ensure, feature_limit, features, finite, invalid, non_negative, partition,
    positive, seq, seq_span,
};
// Their old home: `messages::MAX_SEQ` and `messages::MAX_FEATURE_ID` still resolve.
pub use crate::checks::{MAX_FEATURE_ID, MAX_SEQ};
use crate::error::{ErrorCode, WireError};
use crate::names::WIRE_VERSION;
use crate::wire_serde::{nested, nested_list, nullable, pose};

/// Longest `Error.detail`, in characters.
pub const MAX_DETAIL_CHARS: usize = 1024;

/// A top-level message of the contract.
pub trait Message: Serialize + DeserializeOwned + Clone + std::fmt::Debug {
    /// The `type` value, e.g. `"Frame"`.
    const TYPE: &'static str;

    /// Check ranges, names and consistency (serde has checked the types).
    fn validate(&self) -> Result<(), WireError>;
}

macro_rules! wire_map {
    ($name:ident, [$($field:ident),* $(,)?]) => {
        impl Serialize for $name {
            fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
                let fields: &[&str] = &[$(stringify!($field)),*];
                let mut map = serializer.serialize_map(Some(2 + fields.len()))?;
                map.serialize_entry("type", <$name as Message>::TYPE)?;
                map.serialize_entry("v", &WIRE_VERSION)?;
                $(map.serialize_entry(stringify!($field), &self.$field)?;)*
                map.end()
            }
        }
    };
}

/// One sensor frame of a robot session (robot -> service, `frames` key).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Frame {
    /// Robot-chosen session id; a restarted robot picks a new one.
    pub session: String,
    /// Frame number, strictly increasing within the session.
    pub seq: u64,
    /// Acquisition time in seconds, any epoch (the robot's clock).
    pub stamp_s: f64,
    /// IDs of the features observed; duplicates count once; may be empty.
    pub features: Vec<u64>,
    /// Optional `[x_m, y_m, theta_rad]` in the robot's odometry frame.
    #[serde(default, deserialize_with = "pose")]
    pub pose: Option<[f64; 3]>,
}

impl Message for Frame {
    const TYPE: &'static str = "Frame";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names: session);
        check!(self, "Frame", seq: seq);
        check!(self, "Frame", finite: stamp_s);
        features(&self.features, "Frame.features")?;
        for value in self.pose.iter().flatten() {
            finite(*value, "Frame.pose")?;
        }
        Ok(())
    }
}
wire_map!(Frame, [session, seq, stamp_s, features, pose]);

/// The robot ends its session (robot -> service, on the `frames` key).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionEnd {
    /// Session being ended.
    pub session: String,
    /// Seq of the last frame the robot sent, or `None` if it sent none.
    #[serde(deserialize_with = "nullable")]
    pub last_seq: Option<u64>,
    /// Time of the end in seconds, the robot's clock.
    pub stamp_s: f64,
}

impl Message for SessionEnd {
    const TYPE: &'static str = "SessionEnd";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names: session);
        check!(self, "SessionEnd", seq?: last_seq);
        check!(self, "SessionEnd", finite: stamp_s);
        Ok(())
    }
}
wire_map!(SessionEnd, [session, last_seq, stamp_s]);

/// A submap: the frames of one area and the features seen in it (nested only).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubmapSummary {
    /// Submap id, 0 for the first submap of a session, +1 per transition.
    pub id: u64,
    /// Seq of the first frame of the submap.
    pub first_seq: u64,
    /// Seq of the last frame of the submap so far.
    pub last_seq: u64,
    /// Frames applied to the submap.
    pub frame_count: u64,
    /// Distinct feature IDs seen in the submap, ascending.
    pub features: Vec<u64>,
}

impl SubmapSummary {
    fn validate(&self, at: &str) -> Result<(), WireError> {
        check!(self, at, count: id);
        check!(self, at, seq: first_seq, last_seq);
        check!(self, at, count: frame_count);
        features(&self.features, &format!("{at}.features"))?;
        seq_span(self.first_seq, self.last_seq, at)
    }
}

/// Why the service decided a transition.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reason {
    /// A normalized cut below threshold.
    Spectral,
    /// The CovGraph fell apart.
    Disconnected,
    /// Method `areas`: the last frames fit an area the robot mapped before.
    Recognised,
}

impl Reason {
    /// The reason as written on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            Reason::Spectral => "SPECTRAL",
            Reason::Disconnected => "DISCONNECTED",
            Reason::Recognised => "RECOGNISED",
        }
    }
}

impl Serialize for Reason {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for Reason {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        match String::deserialize(deserializer)?.as_str() {
            "SPECTRAL" => Ok(Reason::Spectral),
            "DISCONNECTED" => Ok(Reason::Disconnected),
            "RECOGNISED" => Ok(Reason::Recognised),
            other => Err(D::Error::custom(format!("unknown reason {other:?}"))),
        }
    }
}

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

/// The robot left one area for another (service -> apps, `transitions` key).
///
/// Identified by `(fleet, robot, session, closed.id)`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Transition {
    /// Fleet of the robot.
    pub fleet: String,
    /// Robot that moved.
    pub robot: String,
    /// Session the frames belong to.
    pub session: String,
    /// Detection frame: the last frame covered by this decision.
    pub seq: u64,
    /// Estimated first frame in the new area; `boundary_seq <= seq`.
    pub boundary_seq: u64,
    /// Stamp of the detection frame, seconds (the robot's clock).
    pub stamp_s: f64,
    /// Spectral split, disconnection, or a recognised area.
    pub reason: Reason,
    /// Normalized cut of the accepted split; set exactly when the reason is `Spectral`.
    #[serde(deserialize_with = "nullable")]
    pub ncut: Option<f64>,
    /// Second smallest generalized eigenvalue; set exactly when the reason is `Spectral`.
    #[serde(deserialize_with = "nullable")]
    pub lambda2: Option<f64>,
    /// The submap left behind; final.
    #[serde(deserialize_with = "nested")]
    pub closed: SubmapSummary,
    /// The submap entered, with its frames so far.
    #[serde(deserialize_with = "nested")]
    pub opened: SubmapSummary,
    /// Features seen on both sides of the boundary, ascending.
    pub boundary_features: Vec<u64>,
    /// The area entered: an [`AreaGraph`] node id.
    pub area: u64,
    /// The area left; never equal to `area`.
    pub left_area: u64,
    /// The robot mapped the area entered before in this session (method `areas` only).
    pub revisit: bool,
    /// Frames covered by this decision (above 1 when the service coalesced frames).
    pub batch_frames: u64,
    /// Service instance that produced it.
    pub instance: String,
    /// The robot's partition.
    pub partition: u16,
    /// Ownership epoch of the partition at the producing instance.
    pub epoch: u64,
}

impl Message for Transition {
    const TYPE: &'static str = "Transition";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names: fleet, robot, session);
        check!(self, "Transition", seq: seq, boundary_seq);
        check!(self, "Transition", finite: stamp_s);
        for value in [self.ncut, self.lambda2].into_iter().flatten() {
            finite(value, "Transition.ncut/lambda2")?;
        }
        self.closed.validate("Transition.closed")?;
        self.opened.validate("Transition.opened")?;
        features(&self.boundary_features, "Transition.boundary_features")?;
        check!(self, "Transition", count: area, left_area);
        check!(self, "Transition", positive: batch_frames);
        check!(self, names: instance);
        check!(self, "Transition", partition: partition);
        check!(self, "Transition", positive: epoch);
        ensure(self.boundary_seq <= self.seq, || {
            format!(
                "boundary_seq {} is after seq {}",
                self.boundary_seq, self.seq
            )
        })?;
        let spectral = self.reason == Reason::Spectral;
        ensure(
            self.ncut.is_some() == spectral && self.lambda2.is_some() == spectral,
            || {
                format!(
                    "{}: ncut, lambda2 are set for SPECTRAL only, null otherwise",
                    self.reason.as_str()
                )
            },
        )?;
        ensure(self.area != self.left_area, || {
            format!(
                "Transition: area {} equals left_area; a transition changes area",
                self.area
            )
        })
    }
}
wire_map!(
    Transition,
    [
        fleet,
        robot,
        session,
        seq,
        boundary_seq,
        stamp_s,
        reason,
        ncut,
        lambda2,
        closed,
        opened,
        boundary_features,
        area,
        left_area,
        revisit,
        batch_frames,
        instance,
        partition,
        epoch,
    ]
);

/// A frame or message was rejected, or frames went missing (service -> apps, `errors` key).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Error {
    /// Fleet of the key the input arrived on.
    #[serde(deserialize_with = "nullable")]
    pub fleet: Option<String>,
    /// Robot of the key the input arrived on.
    #[serde(deserialize_with = "nullable")]
    pub robot: Option<String>,
    /// Session of the offending input, if it could be decoded.
    #[serde(deserialize_with = "nullable")]
    pub session: Option<String>,
    /// What went wrong.
    pub code: ErrorCode,
    /// Human-readable explanation, at most 1024 characters.
    pub detail: String,
    /// Seq of the offending frame, if known.
    #[serde(deserialize_with = "nullable")]
    pub seq: Option<u64>,
    /// When the service saw it, seconds since the Unix epoch (service clock).
    pub stamp_s: f64,
    /// Service instance that reports it.
    pub instance: String,
    /// Ownership epoch of the robot's partition at that instance; `None` when no robot is known.
    #[serde(deserialize_with = "nullable")]
    pub epoch: Option<u64>,
}

impl Message for Error {
    const TYPE: &'static str = "Error";

    fn validate(&self) -> Result<(), WireError> {
        check!(self, names?: fleet, robot, session);
        let chars = self.detail.chars().count();
        if chars > MAX_DETAIL_CHARS {
            return Err(WireError::with_limit(
                ErrorCode::LimitExceeded,
                "max_detail_len",
                format!("Error.detail has {chars} characters; max_detail_len={MAX_DETAIL_CHARS}"),
            ));
        }
        check!(self, "Error", seq?: seq);
        check!(self, "Error", finite: stamp_s);
        check!(self, names: instance);
        check!(self, "Error", positive?: epoch);
        Ok(())
    }
}
wire_map!(
    Error,
    [fleet, robot, session, code, detail, seq, stamp_s, instance, epoch]
);

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

//! The messages of the wire contract v2 (section 5), field for field.
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

use crate::codec::{ErrorCode, WireError};
use crate::names::{validate_name, PARTITIONS, WIRE_VERSION};

/// Largest seq and counter: the largest integer a JavaScript number holds exactly.
pub const MAX_SEQ: u64 = (1 << 53) - 1;
/// Largest feature ID: fits a signed 64-bit integer.
pub const MAX_FEATURE_ID: u64 = (1 << 63) - 1;
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

/// A field that must be present but may be `nil` (serde would default a missing `Option`).
fn nullable<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<Option<T>, D::Error> {
    Option::<T>::deserialize(d)
}

/// A nested struct: only from a msgpack map, never from an array.
fn nested<'de, D: Deserializer<'de>, T: DeserializeOwned>(d: D) -> Result<T, D::Error> {
    let value = rmpv::Value::deserialize(d)?;
    crate::codec::from_value(value).map_err(D::Error::custom)
}

fn nested_list<'de, D: Deserializer<'de>, T: DeserializeOwned>(d: D) -> Result<Vec<T>, D::Error> {
    Vec::<rmpv::Value>::deserialize(d)?
        .into_iter()
        .map(|value| crate::codec::from_value(value).map_err(D::Error::custom))
        .collect()
}

fn pose<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    match Option::<Vec<f64>>::deserialize(d)? {
        None => Ok(None),
        Some(values) => <[f64; 3]>::try_from(values.as_slice())
            .map(Some)
            .map_err(|_| D::Error::custom(format!("a pose has 3 values, not {}", values.len()))),
    }
}

fn invalid(message: String) -> WireError {
    WireError::new(ErrorCode::Invalid, message)
}

fn name(value: &str, what: &str) -> Result<(), WireError> {
    validate_name(value, what)
}

fn opt_name(value: &Option<String>, what: &str) -> Result<(), WireError> {
    value.as_deref().map_or(Ok(()), |v| validate_name(v, what))
}

fn seq(value: u64, field: &str) -> Result<(), WireError> {
    if value > MAX_SEQ {
        return Err(WireError::with_limit(
            ErrorCode::LimitExceeded,
            "max_seq",
            format!("{field}={value} exceeds max_seq={MAX_SEQ}"),
        ));
    }
    Ok(())
}

fn count(value: u64, field: &str) -> Result<(), WireError> {
    if value > MAX_SEQ {
        return Err(invalid(format!("{field}={value} is above 2**53-1")));
    }
    Ok(())
}

fn epoch(value: u64, field: &str) -> Result<(), WireError> {
    if value == 0 || value > MAX_SEQ {
        return Err(invalid(format!("{field}={value} is not in 1..2**53-1")));
    }
    Ok(())
}

fn features(values: &[u64], field: &str) -> Result<(), WireError> {
    if let Some(big) = values.iter().find(|id| **id > MAX_FEATURE_ID) {
        return Err(WireError::with_limit(
            ErrorCode::LimitExceeded,
            "max_feature_id",
            format!("{field} holds {big}; max_feature_id={MAX_FEATURE_ID}"),
        ));
    }
    Ok(())
}

fn finite(value: f64, field: &str) -> Result<(), WireError> {
    if !value.is_finite() {
        return Err(invalid(format!("{field} must be finite, not {value}")));
    }
    Ok(())
}

fn non_negative(value: f64, field: &str) -> Result<(), WireError> {
    finite(value, field)?;
    if value < 0.0 {
        return Err(invalid(format!("{field} must be >= 0, not {value}")));
    }
    Ok(())
}

fn partition(value: u16, field: &str) -> Result<(), WireError> {
    if value >= PARTITIONS {
        return Err(invalid(format!(
            "{field}={value} is not in 0..{}",
            PARTITIONS - 1
        )));
    }
    Ok(())
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
        name(&self.session, "session")?;
        seq(self.seq, "Frame.seq")?;
        finite(self.stamp_s, "Frame.stamp_s")?;
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
        name(&self.session, "session")?;
        if let Some(last) = self.last_seq {
            seq(last, "SessionEnd.last_seq")?;
        }
        finite(self.stamp_s, "SessionEnd.stamp_s")
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
        count(self.id, &format!("{at}.id"))?;
        seq(self.first_seq, &format!("{at}.first_seq"))?;
        seq(self.last_seq, &format!("{at}.last_seq"))?;
        count(self.frame_count, &format!("{at}.frame_count"))?;
        features(&self.features, &format!("{at}.features"))?;
        if self.first_seq > self.last_seq {
            return Err(invalid(format!(
                "{at}: first_seq {} is after last_seq {}",
                self.first_seq, self.last_seq
            )));
        }
        Ok(())
    }
}

/// Why the service decided a transition.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reason {
    /// A normalized cut below threshold.
    Spectral,
    /// The CovGraph fell apart.
    Disconnected,
}

impl Reason {
    /// The reason as written on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            Reason::Spectral => "SPECTRAL",
            Reason::Disconnected => "DISCONNECTED",
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
            other => Err(D::Error::custom(format!("unknown reason {other:?}"))),
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
    /// Spectral split or disconnection.
    pub reason: Reason,
    /// Normalized cut of the accepted split; `None` exactly for `Disconnected`.
    #[serde(deserialize_with = "nullable")]
    pub ncut: Option<f64>,
    /// Second smallest generalized eigenvalue; `None` exactly for `Disconnected`.
    #[serde(deserialize_with = "nullable")]
    pub lambda2: Option<f64>,
    /// The area left behind; final.
    #[serde(deserialize_with = "nested")]
    pub closed: SubmapSummary,
    /// The area entered, with its frames so far.
    #[serde(deserialize_with = "nested")]
    pub opened: SubmapSummary,
    /// Features seen on both sides of the boundary, ascending.
    pub boundary_features: Vec<u64>,
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
        name(&self.fleet, "fleet")?;
        name(&self.robot, "robot")?;
        name(&self.session, "session")?;
        seq(self.seq, "Transition.seq")?;
        seq(self.boundary_seq, "Transition.boundary_seq")?;
        finite(self.stamp_s, "Transition.stamp_s")?;
        for value in [self.ncut, self.lambda2].into_iter().flatten() {
            finite(value, "Transition.ncut/lambda2")?;
        }
        self.closed.validate("Transition.closed")?;
        self.opened.validate("Transition.opened")?;
        features(&self.boundary_features, "Transition.boundary_features")?;
        if self.batch_frames == 0 || self.batch_frames > MAX_SEQ {
            return Err(invalid(format!(
                "Transition.batch_frames={} is not in 1..2**53-1",
                self.batch_frames
            )));
        }
        name(&self.instance, "instance")?;
        partition(self.partition, "Transition.partition")?;
        epoch(self.epoch, "Transition.epoch")?;
        if self.boundary_seq > self.seq {
            return Err(invalid(format!(
                "boundary_seq {} is after seq {}",
                self.boundary_seq, self.seq
            )));
        }
        let spectral = self.reason == Reason::Spectral;
        if self.ncut.is_some() != spectral || self.lambda2.is_some() != spectral {
            return Err(invalid(format!(
                "{}: ncut, lambda2 are set for SPECTRAL, null for DISCONNECTED",
                self.reason.as_str()
            )));
        }
        Ok(())
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
        opt_name(&self.fleet, "fleet")?;
        opt_name(&self.robot, "robot")?;
        opt_name(&self.session, "session")?;
        let chars = self.detail.chars().count();
        if chars > MAX_DETAIL_CHARS {
            return Err(WireError::with_limit(
                ErrorCode::LimitExceeded,
                "max_detail_len",
                format!("Error.detail has {chars} characters; max_detail_len={MAX_DETAIL_CHARS}"),
            ));
        }
        if let Some(value) = self.seq {
            seq(value, "Error.seq")?;
        }
        finite(self.stamp_s, "Error.stamp_s")?;
        name(&self.instance, "instance")?;
        if let Some(value) = self.epoch {
            epoch(value, "Error.epoch")?;
        }
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
        name(&self.fleet, "fleet")?;
        name(&self.robot, "robot")?;
        name(&self.session, "session")?;
        name(&self.instance, "instance")?;
        epoch(self.epoch, "SessionState.epoch")?;
        if let Some(value) = self.last_seq {
            seq(value, "SessionState.last_seq")?;
        }
        count(self.frames_applied, "SessionState.frames_applied")?;
        count(self.frames_duplicate, "SessionState.frames_duplicate")?;
        count(self.frames_missing, "SessionState.frames_missing")?;
        count(self.frames_rejected, "SessionState.frames_rejected")?;
        count(self.transitions, "SessionState.transitions")?;
        self.current_submap
            .validate("SessionState.current_submap")?;
        for (index, summary) in self.closed_submaps.iter().enumerate() {
            summary.validate(&format!("SessionState.closed_submaps.{index}"))?;
        }
        count(self.nodes, "SessionState.nodes")?;
        count(self.edges, "SessionState.edges")
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
        name(&self.fleet, "fleet")?;
        name(&self.robot, "robot")?;
        name(&self.session, "session")?;
        self.summary.validate("Submap.summary")
    }
}
wire_map!(Submap, [fleet, robot, session, summary, open]);

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
        name(&self.instance, "instance")?;
        let chars = self.version.chars().count();
        if chars == 0 || chars > 64 {
            return Err(invalid(format!(
                "Health.version has {chars} characters, not 1..64"
            )));
        }
        count(self.sessions, "Health.sessions")?;
        non_negative(self.uptime_s, "Health.uptime_s")?;
        count(self.frames_applied, "Health.frames_applied")?;
        for p in self.partitions.iter().chain(&self.standby) {
            partition(*p, "Health.partitions")?;
        }
        count(self.queue_depth, "Health.queue_depth")?;
        non_negative(self.lag_s, "Health.lag_s")
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

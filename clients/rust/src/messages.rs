//! The messages of the wire contract v4 (section 5), field for field: those robots put and
//! the service publishes here, the replies of its queryables in `messages/replies.rs`.
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
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::checks::{check, count, ensure, features, finite, partition, positive, seq, seq_span};
// Their old home: `messages::MAX_SEQ` and `messages::MAX_FEATURE_ID` still resolve.
pub use crate::checks::{MAX_FEATURE_ID, MAX_SEQ};
use crate::error::{ErrorCode, WireError};
use crate::wire_serde::{nested, nullable, pose};

/// Longest `Error.detail`, in characters.
pub const MAX_DETAIL_CHARS: usize = 1024;

/// A top-level message of the contract.
pub trait Message: Serialize + DeserializeOwned + Clone + std::fmt::Debug {
    /// The `type` value, e.g. `"Frame"`.
    const TYPE: &'static str;

    /// Check ranges, names and consistency (serde has checked the types).
    fn validate(&self) -> Result<(), WireError>;
}

/// The canonical `Serialize` of a message: `type`, `v`, then the fields in the order given.
macro_rules! wire_map {
    ($name:ident, [$($field:ident),* $(,)?]) => {
        impl ::serde::Serialize for $name {
            fn serialize<S: ::serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
                use ::serde::ser::SerializeMap as _;
                let fields: &[&str] = &[$(stringify!($field)),*];
                let mut map = serializer.serialize_map(Some(2 + fields.len()))?;
                map.serialize_entry("type", <$name as $crate::messages::Message>::TYPE)?;
                map.serialize_entry("v", &$crate::names::WIRE_VERSION)?;
                $(map.serialize_entry(stringify!($field), &self.$field)?;)*
                map.end()
            }
        }
    };
}

mod replies;
pub use replies::{AreaGraph, AreaNode, Health, Method, Passage, SessionState, Submap};

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

/// The robot left one area for another (service -> apps, `transitions` key).
///
/// Identified by `(fleet, robot, session, incarnation, closed.id)`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Transition {
    /// Fleet of the robot.
    pub fleet: String,
    /// Robot that moved.
    pub robot: String,
    /// Session the frames belong to.
    pub session: String,
    /// First seq of the history the decision stands on (0 when nothing was lost); a new
    /// value after the service lost state.
    pub incarnation: u64,
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
        check!(self, "Transition", seq: seq, boundary_seq, incarnation);
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
        ensure(self.incarnation <= self.closed.first_seq, || {
            format!(
                "incarnation {} is after closed.first_seq {}",
                self.incarnation, self.closed.first_seq
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
        incarnation,
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

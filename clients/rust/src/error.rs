//! Every error type of the crate, in a leaf module that imports nothing from the crate, so
//! any module may return them without depending on another.
//!
//! * [`ErrorCode`] and [`WireError`]: bytes, names or limits that break the wire contract (the
//!   `code` an `Error` message reports, section 7).
//! * [`FleetMergeError`]: area graphs that cannot be merged into a fleet's.
//! * [`ClientError`]: what the client API returns; it wraps the two above and Zenoh's errors.

use std::fmt;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Why a message was rejected or a frame was not applied (the `code` of an `Error`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorCode {
    /// Not msgpack, truncated, trailing bytes, nesting too deep, invalid UTF-8, not a map.
    Malformed,
    /// A well-formed map that breaks the schema.
    Invalid,
    /// `type` missing, unknown, or not accepted on this key.
    UnknownType,
    /// `v` missing or not 3.
    UnsupportedVersion,
    /// A name or a key breaks the name rule.
    BadName,
    /// A limit of section 8 was exceeded.
    LimitExceeded,
    /// The frame's seq was already applied.
    DuplicateSeq,
    /// The frame arrived after a later one, inside a gap.
    OutOfOrder,
    /// Frames between the last applied seq and this one never arrived.
    SeqGap,
    /// The service holds as many sessions as it is configured for.
    SessionLimit,
    /// The session's CovGraph reached its configured size.
    GraphLimit,
    /// A frame arrived for a session already closed.
    SessionClosed,
    /// The service failed on valid input.
    Internal,
    /// The service's state store stopped taking checkpoints (kept in memory, retried).
    DurabilityLost,
    /// The state store takes checkpoints again; open sessions were checkpointed anew.
    DurabilityBack,
}

impl ErrorCode {
    /// Every code, in the contract's order.
    pub const ALL: [ErrorCode; 15] = [
        ErrorCode::Malformed,
        ErrorCode::Invalid,
        ErrorCode::UnknownType,
        ErrorCode::UnsupportedVersion,
        ErrorCode::BadName,
        ErrorCode::LimitExceeded,
        ErrorCode::DuplicateSeq,
        ErrorCode::OutOfOrder,
        ErrorCode::SeqGap,
        ErrorCode::SessionLimit,
        ErrorCode::GraphLimit,
        ErrorCode::SessionClosed,
        ErrorCode::Internal,
        ErrorCode::DurabilityLost,
        ErrorCode::DurabilityBack,
    ];

    /// The code as it is written on the wire, e.g. `"SEQ_GAP"`.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::Malformed => "MALFORMED",
            ErrorCode::Invalid => "INVALID",
            ErrorCode::UnknownType => "UNKNOWN_TYPE",
            ErrorCode::UnsupportedVersion => "UNSUPPORTED_VERSION",
            ErrorCode::BadName => "BAD_NAME",
            ErrorCode::LimitExceeded => "LIMIT_EXCEEDED",
            ErrorCode::DuplicateSeq => "DUPLICATE_SEQ",
            ErrorCode::OutOfOrder => "OUT_OF_ORDER",
            ErrorCode::SeqGap => "SEQ_GAP",
            ErrorCode::SessionLimit => "SESSION_LIMIT",
            ErrorCode::GraphLimit => "GRAPH_LIMIT",
            ErrorCode::SessionClosed => "SESSION_CLOSED",
            ErrorCode::Internal => "INTERNAL",
            ErrorCode::DurabilityLost => "DURABILITY_LOST",
            ErrorCode::DurabilityBack => "DURABILITY_BACK",
        }
    }

    /// The code written as `text`, if it is one.
    pub fn parse(text: &str) -> Option<ErrorCode> {
        ErrorCode::ALL
            .into_iter()
            .find(|code| code.as_str() == text)
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Serialize for ErrorCode {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for ErrorCode {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        // Only a msgpack str: an integer must not pass as a variant index.
        let text = String::deserialize(deserializer)?;
        ErrorCode::parse(&text)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown error code {text:?}")))
    }
}

/// Remote bytes or names that break the contract: drop the sample, count it, go on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WireError {
    /// The code a service reports for this failure.
    pub code: ErrorCode,
    /// The [`WireLimits`](crate::codec::WireLimits) field that was exceeded, if a limit caused it.
    pub limit: Option<&'static str>,
    /// What went wrong, for people.
    pub message: String,
}

impl WireError {
    /// A failure with a code and no limit.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        WireError {
            code,
            limit: None,
            message: message.into(),
        }
    }

    /// A failure caused by the limit named `limit`.
    pub fn with_limit(code: ErrorCode, limit: &'static str, message: impl Into<String>) -> Self {
        WireError {
            code,
            limit: Some(limit),
            message: message.into(),
        }
    }

    pub(crate) fn invalid(message: impl Into<String>) -> Self {
        WireError::new(ErrorCode::Invalid, message)
    }

    pub(crate) fn malformed(message: impl Into<String>) -> Self {
        WireError::new(ErrorCode::Malformed, message)
    }
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.code, self.message)
    }
}

impl std::error::Error for WireError {}

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

/// Why graphs cannot be merged.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FleetMergeError {
    /// Graphs of several fleets: a merge is of one fleet.
    SeveralFleets(Vec<String>),
    /// Two graphs of one robot: a merge takes one per robot.
    DuplicateRobot(String),
    /// A threshold out of range.
    BadParams(String),
}

impl fmt::Display for FleetMergeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FleetMergeError::SeveralFleets(fleets) => write!(
                f,
                "area graphs of several fleets ({}): merge one fleet",
                fleets.join(", ")
            ),
            FleetMergeError::DuplicateRobot(robot) => write!(
                f,
                "two area graphs for robot {robot:?}: merge one per robot"
            ),
            FleetMergeError::BadParams(msg) => f.write_str(msg),
        }
    }
}

impl std::error::Error for FleetMergeError {}

//! What a robot publisher is configured with ([`RobotOptions`]) and what it reports about
//! itself ([`RobotStatus`]).

use std::collections::BTreeMap;
use std::time::Duration;

use crate::error::ErrorCode;
use crate::follower::ErrorCallback;
use crate::messages::Error;

/// How long closing waits by default for the service to confirm the end: room for a take-over
/// of the robot's partition, whose catch-up from the cache the service bounds by
/// `catchup_wait_s` (2 s by default).
pub const DEFAULT_CLOSE_TIMEOUT: Duration = Duration::from_secs(5);
/// How a robot publisher behaves.
pub struct RobotOptions {
    /// The session id; a fresh random one by default (a restarted robot must use a new one).
    pub session_id: Option<String>,
    /// Frames kept in the publication cache for recovery by the service.
    pub cache: usize,
    /// Start a new session by itself when the service closed the current one (default
    /// `true`: a closed session discards every frame, and a robot in the field should keep
    /// being segmented). `false`: `publish` fails with `ClientError::SessionClosed`.
    pub auto_new_session: bool,
    /// Called with every `Error` the service reports about this publisher's sessions, on the
    /// publisher's own thread (never Zenoh's), so it may block.
    pub on_error: Option<ErrorCallback>,
    /// How long `close` (and dropping the publisher) waits after the `SessionEnd` for the
    /// service to confirm it, keeping the publication cache meanwhile (default
    /// [`DEFAULT_CLOSE_TIMEOUT`]). `Duration::ZERO`: release right after sending the end.
    pub close_timeout: Duration,
}

impl Default for RobotOptions {
    fn default() -> Self {
        RobotOptions {
            session_id: None,
            cache: 1000,
            auto_new_session: true,
            on_error: None,
            close_timeout: DEFAULT_CLOSE_TIMEOUT,
        }
    }
}

/// What a robot publisher sent and what the service reported back (a snapshot).
#[derive(Clone, Debug)]
pub struct RobotStatus {
    /// Fleet of the robot.
    pub fleet: String,
    /// The robot.
    pub robot: String,
    /// The current session.
    pub session_id: String,
    /// Seq the next frame of the current session will carry.
    pub next_seq: u64,
    /// Last seq sent in the current session.
    pub last_seq: Option<u64>,
    /// Frames published over every session of this publisher.
    pub frames_sent: u64,
    /// Sessions this publisher started.
    pub sessions: usize,
    /// `Error` reports about this publisher's sessions, per code.
    pub errors: BTreeMap<String, u64>,
    /// The latest of them.
    pub last_error: Option<Error>,
    /// The service reported the current session closed.
    pub closed_by_service: bool,
    /// Reports dropped unread because too many were waiting.
    pub reports_dropped: u64,
    /// The robot's partition, the last chunk of its frames key.
    pub partition: u16,
    /// The owner of the partition among the live instances; `None`: nobody serves the robot.
    pub owner: Option<String>,
    /// Reports dropped for an epoch below the highest seen (a deposed owner's).
    pub reports_stale: u64,
}

impl RobotStatus {
    /// Reports received with this code.
    pub fn count(&self, code: ErrorCode) -> u64 {
        self.errors.get(code.as_str()).copied().unwrap_or(0)
    }
}

//! The robot side: publish the frames of one robot session to the lessmap service.
//!
//! Invariants of this file:
//!
//! * Frames go through a zenoh-ext `AdvancedPublisher` with a cache (1000 frames by default)
//!   and publisher detection, so an instance that takes the robot's partition over fetches the
//!   frames it missed (contract section 6, rule 8). Congestion control is *block*: a frame is
//!   never dropped silently.
//! * `SessionEnd` goes on the same key as the frames, so it never overtakes them.
//! * The robot follows its own `errors` key (on a follower thread) and the instances'
//!   liveliness tokens (`follower.rs` has the rules); `publish` acts on what they report.
//! * Closing keeps the publication cache after the `SessionEnd` until the service confirms
//!   the end (its `SessionState` shows the session closed, or open with every frame up to the
//!   last seq applied, then the end is put again): frames dropped at a deposed owner during a
//!   hand-over are fetched from that cache by the new one (section 6, rules 3, 8 and 9). The
//!   wait never fails and never outlasts the close timeout; with no live instance it is skipped.
//!   [`close_all`] closes many publishers with one shared wait (`closing.rs`); a single close
//!   is `close_all` of one publisher.

use std::collections::hash_map::RandomState;
use std::hash::{BuildHasher, Hasher};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use zenoh::pubsub::Subscriber;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};
use zenoh_ext::{AdvancedPublisher, AdvancedPublisherBuilderExt, CacheConfig};

use crate::closing::{close_each, CloseReport, Ending, EndingPublisher};
// Their old home: `robot::EndProgress` and `robot::end_progress` still resolve.
pub use crate::closing::{end_progress, EndProgress};
use crate::codec::{encode, encoding, WireLimits};
use crate::error::{ClientError, ErrorCode, WireError};
// Its old home: `robot::ErrorCallback` still resolves.
pub use crate::follower::ErrorCallback;
use crate::follower::{follow_errors, follow_instances, Shared};
use crate::messages::{AreaGraph, Frame, Message, SessionEnd, SessionState};
use crate::names::{keys, owner_and_standby, partition_of, validate_name};
use crate::query;

mod options;
pub use options::{RobotOptions, RobotStatus, DEFAULT_CLOSE_TIMEOUT};

/// A fresh session id: the start time plus randomness, a valid name.
pub fn new_session_id() -> String {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    // RandomState is seeded per process from the OS: enough to keep restarts apart.
    let mut hasher = RandomState::new().build_hasher();
    hasher.write_u128(
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    hasher.write_u32(std::process::id());
    format!("{secs}-{:012x}", hasher.finish() & 0xffff_ffff_ffff)
}

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Publishes the frames of one robot session, numbered from 0, and follows its errors.
///
/// Declare one with `Connection::robot`. `close` (or dropping it) ends the session with a
/// `SessionEnd` carrying the last seq, so the service frees it at once, and keeps the
/// publication cache until the service confirms the end (at most
/// [`RobotOptions::close_timeout`]).
pub struct RobotPublisher {
    fleet: String,
    robot: String,
    partition: u16,
    key: String,
    session: Session,
    auto_new_session: bool,
    close_timeout: Duration,
    limits: WireLimits,
    shared: Arc<Shared>,
    publisher: Option<AdvancedPublisher<'static>>,
    errors_sub: Option<Subscriber<()>>,
    live_sub: Option<Subscriber<()>>,
    follower: Option<JoinHandle<()>>,
}

impl RobotPublisher {
    pub(crate) fn new(
        session: Session,
        fleet: &str,
        robot: &str,
        options: RobotOptions,
    ) -> Result<RobotPublisher, ClientError> {
        validate_name(fleet, "fleet")?;
        validate_name(robot, "robot")?;
        let session_id = options.session_id.unwrap_or_else(new_session_id);
        validate_name(&session_id, "session")?;
        let key = keys::frames(fleet, robot)?;
        let shared = Arc::new(Shared::new(session_id));
        let publisher = session
            .declare_publisher(key.clone())
            .encoding(encoding::<Frame>())
            .congestion_control(CongestionControl::Block)
            .cache(CacheConfig::default().max_samples(options.cache))
            .publisher_detection()
            .wait()?;
        let mut robot_pub = RobotPublisher {
            fleet: fleet.to_owned(),
            robot: robot.to_owned(),
            partition: partition_of(fleet, robot),
            key,
            session: session.clone(),
            auto_new_session: options.auto_new_session,
            close_timeout: options.close_timeout,
            limits: WireLimits::default(),
            shared: Arc::clone(&shared),
            publisher: Some(publisher),
            errors_sub: None,
            live_sub: None,
            follower: None,
        };
        let (errors_sub, follower) = follow_errors(
            &session,
            fleet,
            robot,
            Arc::clone(&shared),
            options.auto_new_session,
            options.on_error,
        )?;
        robot_pub.errors_sub = Some(errors_sub);
        robot_pub.follower = Some(follower);
        robot_pub.live_sub = Some(follow_instances(&session, Arc::clone(&shared))?);
        Ok(robot_pub)
    }

    /// Fleet of the robot.
    pub fn fleet(&self) -> &str {
        &self.fleet
    }

    /// The robot's name.
    pub fn robot(&self) -> &str {
        &self.robot
    }

    /// The robot's partition: the last chunk of its frames key.
    pub fn partition(&self) -> u16 {
        self.partition
    }

    /// The current session id.
    pub fn session_id(&self) -> String {
        self.shared.lock().session_id.clone()
    }

    /// Seq the next frame will carry.
    pub fn next_seq(&self) -> u64 {
        self.shared.lock().next_seq
    }

    /// A snapshot of what was sent and what the service reported about it.
    pub fn status(&self) -> RobotStatus {
        let state = self.shared.lock();
        let live: Vec<&String> = state.live.iter().collect();
        RobotStatus {
            fleet: self.fleet.clone(),
            robot: self.robot.clone(),
            session_id: state.session_id.clone(),
            next_seq: state.next_seq,
            last_seq: state.next_seq.checked_sub(1),
            frames_sent: state.frames_sent,
            sessions: state.sessions.len(),
            errors: state.errors.clone(),
            last_error: state.last_error.clone(),
            closed_by_service: state.closed_report,
            reports_dropped: self.shared.dropped.load(Ordering::Relaxed),
            partition: self.partition,
            owner: owner_and_standby(self.partition, &live).0,
            reports_stale: state.stale,
        }
    }

    /// Wait until every error report received so far is handled (counted in `status`, handed
    /// to `on_error`); `false` after `timeout`. Reports still on the network are not waited for.
    pub fn flush_errors(&self, timeout: Duration) -> bool {
        if let Some(follower) = &self.follower {
            if follower.thread().id() == std::thread::current().id() {
                return true; // waiting for ourselves would never end
            }
        }
        let deadline = Instant::now() + timeout;
        let mut inbox = self.shared.inbox();
        let target = inbox.received;
        while inbox.handled < target {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() || self.follower.is_none() {
                return false;
            }
            inbox = self
                .shared
                .inbox_changed
                .wait_timeout(inbox, left)
                .unwrap_or_else(|poisoned| poisoned.into_inner())
                .0;
        }
        true
    }

    /// Publish one frame stamped now, with the next seq; return that seq.
    pub fn publish(&self, features: &[u64]) -> Result<u64, ClientError> {
        self.publish_frame(features, None, None, None)
    }

    /// Publish one frame and return its seq.
    ///
    /// `stamp_s` defaults to now; `seq` to the next one (an explicit seq must not be below
    /// it; a gap is reported by the service). After a new session the numbering starts at 0.
    /// A frame that breaks a limit or a type rule is a `ClientError::Wire` and nothing is sent.
    pub fn publish_frame(
        &self,
        features: &[u64],
        stamp_s: Option<f64>,
        pose: Option<[f64; 3]>,
        seq: Option<u64>,
    ) -> Result<u64, ClientError> {
        let publisher = self.publisher.as_ref().ok_or(ClientError::Closed)?;
        let (session_id, next_seq) = {
            let mut state = self.shared.lock();
            if state.closed_report {
                if let Some(holder) = &state.holder {
                    return Err(ClientError::SessionClosed(format!(
                        "{}/{}: the service closed session {}; session {holder} is open for \
                         this robot name, from another publisher (new_session would close it)",
                        self.fleet, self.robot, state.session_id
                    )));
                }
                if !self.auto_new_session {
                    return Err(ClientError::SessionClosed(format!(
                        "{}/{}: the service closed session {}",
                        self.fleet, self.robot, state.session_id
                    )));
                }
                let old = state.session_id.clone();
                state.start_session(new_session_id());
                tracing::warn!(
                    "{}/{}: the service closed session {old}; publishing under new session {}",
                    self.fleet,
                    self.robot,
                    state.session_id
                );
            }
            (state.session_id.clone(), state.next_seq)
        };
        if features.len() > self.limits.max_features_per_frame {
            return Err(WireError::with_limit(
                ErrorCode::LimitExceeded,
                "max_features_per_frame",
                format!(
                    "frame has {} features, over max_features_per_frame={}",
                    features.len(),
                    self.limits.max_features_per_frame
                ),
            )
            .into());
        }
        let frame_seq = seq.unwrap_or(next_seq);
        if frame_seq < next_seq {
            return Err(WireError::new(
                ErrorCode::OutOfOrder,
                format!("seq {frame_seq} is before the next seq {next_seq}"),
            )
            .into());
        }
        let frame = Frame {
            session: session_id.clone(),
            seq: frame_seq,
            stamp_s: stamp_s.unwrap_or_else(now_s),
            features: features.to_vec(),
            pose,
        };
        frame.validate()?;
        let payload = encode(&frame);
        if payload.len() > self.limits.max_payload_bytes {
            return Err(WireError::with_limit(
                ErrorCode::LimitExceeded,
                "max_payload_bytes",
                format!("frame of {} bytes, over max_payload_bytes", payload.len()),
            )
            .into());
        }
        publisher.put(payload).wait()?;
        let mut state = self.shared.lock();
        state.frames_sent += 1;
        if state.session_id == session_id {
            state.next_seq = frame_seq + 1;
        }
        Ok(frame_seq)
    }

    /// End the current session (unless the service closed it) and start a new one; return
    /// its id. The next frame carries seq 0.
    pub fn new_session(&self, session_id: Option<&str>) -> Result<String, ClientError> {
        if self.publisher.is_none() {
            return Err(ClientError::Closed);
        }
        let new_id = session_id.map_or_else(new_session_id, str::to_owned);
        validate_name(&new_id, "session")?;
        let (old, last, still_open) = {
            let mut state = self.shared.lock();
            if state.sessions.contains(&new_id) {
                return Err(ClientError::SessionClosed(format!(
                    "session id {new_id:?} was already used by this publisher"
                )));
            }
            let old = (
                state.session_id.clone(),
                state.next_seq.checked_sub(1),
                !state.closed_report,
            );
            state.start_session(new_id.clone());
            old
        };
        if still_open {
            self.send_end(&old, last)?;
        }
        Ok(new_id)
    }

    /// Wait until the robot's partition has an owner that serves it; `false` after `timeout`.
    ///
    /// The owner is the first of the live instances by rendezvous ranking. A new owner takes
    /// its partitions a moment after its token appears, so this also asks the owner's
    /// `Health` until it lists the partition (an owner that does not answer is taken at its
    /// token), and last waits until the owner's frames subscription matches this robot's key,
    /// so the next frame is routed to it.
    pub fn wait_for_service(&self, timeout: Duration) -> Result<bool, ClientError> {
        let deadline = Instant::now() + timeout;
        let publisher = self.publisher.as_ref().ok_or(ClientError::Closed)?;
        loop {
            let owner = {
                let mut state = self.shared.lock();
                loop {
                    let live: Vec<&String> = state.live.iter().collect();
                    if let Some(owner) = owner_and_standby(self.partition, &live).0 {
                        break owner;
                    }
                    let left = deadline.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        return Ok(false);
                    }
                    state = self
                        .shared
                        .live_changed
                        .wait_timeout(state, left)
                        .unwrap_or_else(|poisoned| poisoned.into_inner())
                        .0;
                }
            };
            let ask = deadline
                .saturating_duration_since(Instant::now())
                .clamp(Duration::from_millis(100), Duration::from_secs(1));
            if query::owner_serves(&self.session, &owner, self.partition, ask)? {
                while !publisher.matching_status().wait()?.matching() {
                    if Instant::now() >= deadline {
                        return Ok(false);
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
                return Ok(true);
            }
            if Instant::now() >= deadline {
                return Ok(false);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The service's state of the current session, or `None` (no frame of it arrived yet, no
    /// service, or the service holds another session for this robot name).
    pub fn state(&self, timeout: Duration) -> Result<Option<SessionState>, ClientError> {
        let session_id = self.session_id();
        let states = query::states(&self.session, &self.fleet, &self.robot, timeout)?;
        Ok(states
            .into_iter()
            .next()
            .filter(|state| state.session == session_id))
    }

    /// The areas of the current session and the passages between them, or `None` (as for
    /// [`RobotPublisher::state`]).
    pub fn area_graph(&self, timeout: Duration) -> Result<Option<AreaGraph>, ClientError> {
        let session_id = self.session_id();
        let graphs = query::area_graphs(&self.session, &self.fleet, &self.robot, timeout)?;
        Ok(graphs
            .into_iter()
            .next()
            .filter(|graph| graph.session == session_id))
    }

    fn send_end(&self, session_id: &str, last_seq: Option<u64>) -> Result<(), ClientError> {
        let end = SessionEnd {
            session: session_id.to_owned(),
            last_seq,
            stamp_s: now_s(),
        };
        // Same key as the frames: Zenoh keeps the order of puts on one key.
        self.session
            .put(self.key.as_str(), encode(&end))
            .encoding(encoding::<SessionEnd>())
            .congestion_control(CongestionControl::Block)
            .wait()?;
        Ok(())
    }

    /// End the session explicitly (a `SessionEnd` with the last seq), wait until the service
    /// confirms the end, then release everything. Dropping the publisher does the same,
    /// logging errors instead of returning them.
    ///
    /// The publication cache stays until the service's `SessionState` shows the session
    /// closed, or open with every frame up to the last seq applied (then the end is put again
    /// after 0.3 s): if the robot's partition moves between instances at that moment, the
    /// frames queued at the old owner are lost there and the new owner fetches them from this
    /// cache. Polls the robot's `state` key every 20-250 ms, for at most
    /// [`RobotOptions::close_timeout`]; then, or at once when no service instance is alive or
    /// a query fails, it logs one warning and releases anyway. An unconfirmed end is never an
    /// error. No wait when no frame was sent or the service had closed the session. Closing
    /// many robots: [`close_all`], which waits for them together and reports the ends left
    /// unconfirmed.
    ///
    /// Fails only when the end could not be sent or a declaration could not be released (the
    /// publisher is released as far as it can be either way).
    pub fn close(mut self) -> Result<(), ClientError> {
        let timeout = self.close_timeout;
        self.shut(timeout)
    }

    /// `close`, waiting at most `timeout` for the confirmation (`Duration::ZERO`: none).
    pub fn close_within(mut self, timeout: Duration) -> Result<(), ClientError> {
        self.shut(timeout)
    }

    fn shut(&mut self, timeout: Duration) -> Result<(), ClientError> {
        let report = close_each(vec![self as &mut dyn EndingPublisher], timeout);
        match report.failures.into_iter().next() {
            Some(failure) => Err(failure.error),
            None => Ok(()),
        }
    }
}

impl EndingPublisher for RobotPublisher {
    fn fleet(&self) -> &str {
        &self.fleet
    }

    fn robot(&self) -> &str {
        &self.robot
    }

    fn zenoh_session(&self) -> &Session {
        &self.session
    }

    fn knows_live_instance(&self) -> bool {
        !self.shared.lock().live.is_empty()
    }

    fn closed_by_service(&self) -> bool {
        self.shared.lock().closed_report
    }

    fn resend_end(&self, session_id: &str, last_seq: u64) {
        if let Err(err) = self.send_end(session_id, Some(last_seq)) {
            tracing::debug!(
                "{}/{}: putting the end again: {err}",
                self.fleet,
                self.robot
            );
        }
    }

    fn end_for_close(&mut self, confirm: bool) -> Option<Ending> {
        self.publisher.as_ref()?;
        let (session_id, last, still_open) = {
            let state = self.shared.lock();
            (
                state.session_id.clone(),
                state.next_seq.checked_sub(1),
                !state.closed_report,
            )
        };
        let sent = if still_open {
            self.send_end(&session_id, last)
        } else {
            Ok(())
        };
        let to_confirm = match (still_open && sent.is_ok() && confirm, last) {
            (true, Some(last)) => Some((session_id, last)),
            _ => None,
        };
        Some(Ending { sent, to_confirm })
    }

    fn release(&mut self) -> Result<(), ClientError> {
        self.shared.stop.store(true, Ordering::Relaxed);
        let mut first: Result<(), ClientError> = Ok(());
        let mut note = |result: zenoh::Result<()>| {
            if let (Err(err), true) = (result, first.is_ok()) {
                first = Err(err.into());
            }
        };
        if let Some(sub) = self.errors_sub.take() {
            note(sub.undeclare().wait());
        }
        if let Some(sub) = self.live_sub.take() {
            note(sub.undeclare().wait());
        }
        if let Some(follower) = self.follower.take() {
            if follower.thread().id() != std::thread::current().id() {
                let _ = follower.join();
            }
        }
        if let Some(publisher) = self.publisher.take() {
            note(publisher.undeclare().wait());
        }
        first
    }
}

impl Drop for RobotPublisher {
    fn drop(&mut self) {
        let timeout = self.close_timeout;
        if let Err(err) = self.shut(timeout) {
            tracing::warn!(
                "{}/{}: closing the robot publisher: {err}",
                self.fleet,
                self.robot
            );
        }
    }
}

/// Close many robot publishers together: every end first, then one wait for them all, then
/// every release. Returns what was left unconfirmed or failed; never fails, never panics.
///
/// [`RobotPublisher::close`] one after the other costs one confirmation latency per robot;
/// this sends every `SessionEnd`, then polls the states of all the robots at once (one query
/// per Zenoh session and fleet, with a wildcard key when several robots of a fleet wait),
/// then releases every publisher. The rules of `close` apply: at most `timeout` of waiting
/// (each robot's own [`RobotOptions::close_timeout`] is not used), no wait for robots with no
/// live instance on their network, one warning line for the ends left unconfirmed (per
/// reason), which the report lists too. `Duration::ZERO` releases right after the ends.
///
/// ```no_run
/// use std::time::Duration;
/// use lessmap_client::{close_all, Connection};
///
/// let conn = Connection::connect(&["tcp/127.0.0.1:7447"], Duration::from_secs(10))?;
/// let robots = (0..16)
///     .map(|i| conn.robot("warehouse", &format!("amr-{i}")))
///     .collect::<Result<Vec<_>, _>>()?;
/// for robot in &robots {
///     robot.publish(&[12, 40, 41, 97])?;
/// }
/// let report = close_all(robots, lessmap_client::DEFAULT_CLOSE_TIMEOUT);
/// for end in &report.unconfirmed {
///     eprintln!("{}/{}: {}", end.fleet, end.robot, end.reason);
/// }
/// # Ok::<(), lessmap_client::ClientError>(())
/// ```
pub fn close_all<I>(publishers: I, timeout: Duration) -> CloseReport
where
    I: IntoIterator<Item = RobotPublisher>,
{
    let mut robots: Vec<RobotPublisher> = publishers.into_iter().collect();
    let borrowed = robots
        .iter_mut()
        .map(|robot| robot as &mut dyn EndingPublisher)
        .collect();
    let report = close_each(borrowed, timeout);
    for failure in &report.failures {
        tracing::warn!(
            "{}/{}: closing the robot publisher: {}",
            failure.fleet,
            failure.robot,
            failure.error
        );
    }
    drop(robots); // closed: dropping them does nothing more
    report
}

//! Ending robot sessions: keep the publication caches until the service confirms the ends
//! (the Python SDK's `lessmap_client.closing`).
//!
//! A robot's publication cache is the only copy of the frames the service has not applied yet.
//! When a partition moves between instances as a robot ends its session, the frames (and the
//! `SessionEnd`) queued at the old owner are dropped there, and the new owner fetches them
//! from the cache (contract section 6, rules 8 and 9). A publisher that released its cache
//! right after the end would lose them, so the ends are confirmed first, by the robots'
//! `SessionState`.
//!
//! Closing runs in three steps over every publisher given (`close_each`; `close_all` and a
//! single `close` both use it): every end is sent, then one wait confirms them all, then every
//! publisher is released. This module reaches the publishers through `EndingPublisher`.
//!
//! Invariants of this file:
//!
//! * It never fails and never waits past the deadline by more than one bounded query (a query
//!   is bounded by what is left, and by at least 50 ms).
//! * One state query per Zenoh session and fleet per poll, whatever the number of robots
//!   waiting: a fleet's robots are asked with one wildcard key when several wait.
//! * A robot is confirmed when the service's current state shows its session closed, or open
//!   with every frame up to the robot's last seq applied (then only the end is missing: it is
//!   put again after 0.3 s, which the service ignores if it had it, section 6 rule 3),
//!   or when the service reported the session closed (`SESSION_CLOSED`).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt;
use std::time::{Duration, Instant};

use zenoh::session::ZenohId;
use zenoh::Session;

use crate::error::ClientError;
use crate::messages::SessionState;
use crate::names::keys;
use crate::query::{current_states, get_all, instances};

/// Pauses before the state polls, in ms: the first is short (a live end is handled within a
/// receiver sweep, 10-50 ms); later ones grow, so a slow take-over costs few queries.
const POLL_DELAYS_MS: [u64; 5] = [20, 50, 100, 200, 250];
/// A session open with every frame applied gets this long for its end to arrive before the end
/// is put again (it may have been dropped with the frames queued at a deposed owner).
const END_GRACE: Duration = Duration::from_millis(300);
const STATE_QUERY_MAX: Duration = Duration::from_secs(1);
const INSTANCES_QUERY_MAX: Duration = Duration::from_millis(500);
const QUERY_MIN: Duration = Duration::from_millis(50);

/// Why the service did not confirm a session end.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum UnconfirmedReason {
    /// No live lessmap instance on the robot's network (no token, confirmed by one liveliness
    /// query): nobody could confirm, so the end was not waited for.
    NoLiveInstance,
    /// A state query failed (a closed Zenoh session, say); the error's text.
    QueryFailed(String),
    /// Not confirmed within the close timeout (a take-over that did not finish, or no
    /// instance answering for the robot).
    TimedOut(Duration),
}

impl fmt::Display for UnconfirmedReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            UnconfirmedReason::NoLiveInstance => f.write_str("no live lessmap instance"),
            UnconfirmedReason::QueryFailed(err) => write!(f, "state query failed ({err})"),
            UnconfirmedReason::TimedOut(timeout) => write!(f, "not confirmed within {timeout:?}"),
        }
    }
}

/// A session end the service did not confirm. The publication cache was released anyway, so
/// frames of the session the service had not applied yet are lost.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnconfirmedEnd {
    /// Fleet of the robot.
    pub fleet: String,
    /// The robot.
    pub robot: String,
    /// The session ended.
    pub session: String,
    /// Its last frame.
    pub last_seq: u64,
    /// Why it is not confirmed.
    pub reason: UnconfirmedReason,
}

/// A robot publisher whose end could not be sent, or whose declarations could not be
/// released (it is closed all the same).
#[derive(Debug)]
pub struct CloseFailure {
    /// Fleet of the robot.
    pub fleet: String,
    /// The robot.
    pub robot: String,
    /// What failed.
    pub error: ClientError,
}

/// What [`close_all`](crate::close_all) did.
///
/// An unconfirmed end is not a failure of the call: the publisher is closed either way, and
/// the service closes the session by itself when it has not seen a frame of it for a while.
#[derive(Debug, Default)]
pub struct CloseReport {
    /// Publishers closed by the call.
    pub closed: usize,
    /// Ends sent whose confirmation the service did not give, in the order the publishers
    /// were given. Ends that need none are not listed: sessions without a frame, sessions the
    /// service had closed, and every end when the timeout is zero (nothing was waited for).
    pub unconfirmed: Vec<UnconfirmedEnd>,
    /// Ends that could not be sent and releases that failed.
    pub failures: Vec<CloseFailure>,
}

impl CloseReport {
    /// Every end sent, every one confirmed (or needing no confirmation), every release done.
    pub fn is_clean(&self) -> bool {
        self.unconfirmed.is_empty() && self.failures.is_empty()
    }
}

/// What the service's state of a robot says about a session end the robot sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EndProgress {
    /// The session is closed: the end is confirmed and the cache is no longer needed.
    Closed,
    /// Open with every frame up to the last seq applied: only the end is missing (it may have
    /// been dropped at a deposed owner), so it is put again after a short grace.
    CaughtUp,
    /// Frames still to apply, no state yet (a take-over in progress), or the newest state is
    /// about another session: the cache may still be needed.
    Pending,
}

/// Where the end of `session` (last frame `last_seq`) of `fleet`/`robot` stands, per the
/// `SessionState` replies of its `state` key: of several replies (an old and a new owner),
/// the highest epoch is current.
pub fn end_progress(
    replies: Vec<SessionState>,
    fleet: &str,
    robot: &str,
    session: &str,
    last_seq: u64,
) -> EndProgress {
    let current = current_states(replies)
        .into_iter()
        .find(|state| state.fleet == fleet && state.robot == robot);
    progress_of(current.as_ref(), session, last_seq)
}

/// Where the end of `session` (last frame `last_seq`) stands per the robot's current state.
pub(crate) fn progress_of(
    current: Option<&SessionState>,
    session: &str,
    last_seq: u64,
) -> EndProgress {
    match current {
        // Another session is no proof either way: it may be older than this one.
        Some(state) if state.session == session => {
            if !state.open {
                EndProgress::Closed
            } else if state.last_seq.is_some_and(|seq| seq >= last_seq) {
                EndProgress::CaughtUp
            } else {
                EndProgress::Pending
            }
        }
        _ => EndProgress::Pending,
    }
}

/// What the wait for the ends asks of a robot publisher. `RobotPublisher` implements it; a
/// trait keeps this module below the publisher's, which calls [`confirm_ends`].
pub(crate) trait EndingPublisher {
    /// Fleet of the robot.
    fn fleet(&self) -> &str;
    /// The robot.
    fn robot(&self) -> &str;
    /// The Zenoh session the publisher puts on: one query per session serves its robots.
    fn zenoh_session(&self) -> &Session;
    /// Whether the publisher has seen a live instance's token.
    fn knows_live_instance(&self) -> bool;
    /// Whether the service reported the current session closed.
    fn closed_by_service(&self) -> bool;
    /// Put the end of `session_id` again (ignored by the service if it had it).
    fn resend_end(&self, session_id: &str, last_seq: u64);
    /// Send the end of a publisher not released yet; `None` when it was released already.
    /// The publication cache stays until `release`.
    fn end_for_close(&mut self, confirm: bool) -> Option<Ending>;
    /// Stop following errors and instances, then undeclare the publisher (its cache goes with
    /// it). Every step runs; the first error is returned.
    fn release(&mut self) -> Result<(), ClientError>;
}

/// What a publisher's end did: whether it went out, and the end to confirm (the session and its
/// last seq) when confirmation was asked for and one is needed (no frame sent, or a session the
/// service closed, needs none).
pub(crate) struct Ending {
    pub(crate) sent: Result<(), ClientError>,
    pub(crate) to_confirm: Option<(String, u64)>,
}

/// A session end sent and not confirmed yet (one per robot publisher).
pub(crate) struct PendingEnd<'a> {
    /// Position of the publisher among those closed together (the report's order).
    pub(crate) index: usize,
    pub(crate) robot: &'a dyn EndingPublisher,
    pub(crate) session: String,
    pub(crate) last_seq: u64,
    caught_up_at: Option<Instant>,
}

impl<'a> PendingEnd<'a> {
    pub(crate) fn new(
        index: usize,
        robot: &'a dyn EndingPublisher,
        session: String,
        last_seq: u64,
    ) -> Self {
        PendingEnd {
            index,
            robot,
            session,
            last_seq,
            caught_up_at: None,
        }
    }

    fn unconfirmed(self, reason: UnconfirmedReason) -> (usize, UnconfirmedEnd) {
        (
            self.index,
            UnconfirmedEnd {
                fleet: self.robot.fleet().to_owned(),
                robot: self.robot.robot().to_owned(),
                session: self.session,
                last_seq: self.last_seq,
                reason,
            },
        )
    }

    fn resend(&self) {
        // Ignored by the service if it had the end.
        self.robot.resend_end(&self.session, self.last_seq);
    }

    /// Whether the end is confirmed per `states` (the current state of each robot asked).
    fn confirmed(
        &mut self,
        states: &HashMap<(String, String), SessionState>,
        now: Instant,
    ) -> bool {
        if self.robot.closed_by_service() {
            return true; // the service closed it (SESSION_CLOSED): nothing more will apply
        }
        let robot = (self.robot.fleet().to_owned(), self.robot.robot().to_owned());
        match progress_of(states.get(&robot), &self.session, self.last_seq) {
            EndProgress::Closed => true,
            EndProgress::Pending => {
                self.caught_up_at = None;
                false
            }
            EndProgress::CaughtUp => match self.caught_up_at {
                None => {
                    self.caught_up_at = Some(now);
                    false
                }
                Some(at) if now.duration_since(at) >= END_GRACE => {
                    self.resend();
                    true
                }
                Some(_) => false,
            },
        }
    }
}

/// Wait until the service confirms every end, at most `timeout`; return the rest, in the order
/// of their `index`.
///
/// Gives up at once on the robots of a network with no live service instance (nobody can
/// confirm, and waiting would only delay the caller) or whose state query fails.
pub(crate) fn confirm_ends(ends: Vec<PendingEnd<'_>>, timeout: Duration) -> Vec<UnconfirmedEnd> {
    let deadline = Instant::now() + timeout;
    let mut waiting = ends;
    let mut given_up: Vec<(usize, UnconfirmedEnd)> = Vec::new();
    let mut delays = POLL_DELAYS_MS.iter();
    while !waiting.is_empty() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            break;
        }
        let pause = Duration::from_millis(*delays.next().unwrap_or(&POLL_DELAYS_MS[4]));
        std::thread::sleep(pause.min(left));
        let mut still = Vec::new();
        for group in by_route(waiting) {
            if !anyone_alive(&group, deadline) {
                let reason = UnconfirmedReason::NoLiveInstance;
                given_up.extend(group.into_iter().map(|end| end.unconfirmed(reason.clone())));
                continue;
            }
            let states = match current_states_of(&group, deadline) {
                Ok(states) => states,
                Err(err) => {
                    let reason = UnconfirmedReason::QueryFailed(err.to_string());
                    given_up.extend(group.into_iter().map(|end| end.unconfirmed(reason.clone())));
                    continue;
                }
            };
            let now = Instant::now();
            for mut end in group {
                if !end.confirmed(&states, now) {
                    still.push(end);
                }
            }
        }
        waiting = still;
    }
    // Out of time: a session with every frame applied lacks only its end; the cache is not
    // needed for it any more.
    for end in waiting {
        if end.caught_up_at.is_some() {
            end.resend();
        } else {
            given_up.push(end.unconfirmed(UnconfirmedReason::TimedOut(timeout)));
        }
    }
    given_up.sort_by_key(|(index, _)| *index);
    given_up.into_iter().map(|(_, end)| end).collect()
}

/// The ends grouped by the Zenoh session their publishers use: one query serves a group.
fn by_route(ends: Vec<PendingEnd<'_>>) -> Vec<Vec<PendingEnd<'_>>> {
    let mut groups: Vec<(ZenohId, Vec<PendingEnd<'_>>)> = Vec::new();
    for end in ends {
        let zid = end.robot.zenoh_session().zid();
        match groups.iter_mut().find(|(id, _)| *id == zid) {
            Some((_, group)) => group.push(end),
            None => groups.push((zid, vec![end])),
        }
    }
    groups.into_iter().map(|(_, group)| group).collect()
}

/// What is left until `deadline`, as a query timeout between `QUERY_MIN` and `max`.
fn query_timeout(deadline: Instant, max: Duration) -> Duration {
    deadline
        .saturating_duration_since(Instant::now())
        .clamp(QUERY_MIN, max)
}

/// A live instance per the publishers' tokens, else per one liveliness query (for publishers
/// closed so soon after they were declared that the tokens had not reached them yet).
fn anyone_alive(group: &[PendingEnd<'_>], deadline: Instant) -> bool {
    if group.iter().any(|end| end.robot.knows_live_instance()) {
        return true;
    }
    let session = group[0].robot.zenoh_session();
    instances(session, query_timeout(deadline, INSTANCES_QUERY_MAX))
        .is_ok_and(|live| !live.is_empty())
}

/// The current state of the group's robots: one query per fleet (wildcard if several robots).
fn current_states_of(
    group: &[PendingEnd<'_>],
    deadline: Instant,
) -> Result<HashMap<(String, String), SessionState>, ClientError> {
    let mut robots: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    for end in group {
        robots
            .entry(end.robot.fleet())
            .or_default()
            .insert(end.robot.robot());
    }
    let session = group[0].robot.zenoh_session();
    let mut found = Vec::new();
    for (fleet, names) in robots {
        let robot = match names.iter().next() {
            Some(only) if names.len() == 1 => *only,
            _ => "*",
        };
        let key = keys::state(fleet, robot)?;
        found.extend(get_all::<SessionState>(
            session,
            &key,
            query_timeout(deadline, STATE_QUERY_MAX),
        )?);
    }
    // Of several replies for a robot (an old and a new owner), the highest epoch is current.
    Ok(current_states(found)
        .into_iter()
        .map(|state| ((state.fleet.clone(), state.robot.clone()), state))
        .collect())
}

/// `close_all` over publishers borrowed (a single `close` and `Drop` use it too).
pub(crate) fn close_each(
    mut robots: Vec<&mut dyn EndingPublisher>,
    timeout: Duration,
) -> CloseReport {
    let mut report = CloseReport::default();
    let mut closing = Vec::with_capacity(robots.len());
    let mut pending = Vec::new();
    for (index, robot) in robots.iter_mut().enumerate() {
        let Some(Ending { sent, to_confirm }) = robot.end_for_close(!timeout.is_zero()) else {
            continue; // closed already
        };
        closing.push(index);
        if let Err(error) = sent {
            report.failures.push(CloseFailure {
                fleet: robot.fleet().to_owned(),
                robot: robot.robot().to_owned(),
                error,
            });
        }
        if let Some((session, last_seq)) = to_confirm {
            pending.push((index, session, last_seq));
        }
    }
    if !pending.is_empty() {
        // The caches live with the publishers until their release below.
        let ends = pending
            .into_iter()
            .map(|(index, session, last_seq)| {
                PendingEnd::new(index, &*robots[index], session, last_seq)
            })
            .collect();
        report.unconfirmed = confirm_ends(ends, timeout);
        warn_unconfirmed(&report.unconfirmed);
    }
    for index in closing {
        let robot = &mut robots[index];
        if let Err(error) = robot.release() {
            report.failures.push(CloseFailure {
                fleet: robot.fleet().to_owned(),
                robot: robot.robot().to_owned(),
                error,
            });
        }
        report.closed += 1;
    }
    report
}

/// One warning line per reason for the ends left unconfirmed.
fn warn_unconfirmed(ends: &[UnconfirmedEnd]) {
    let mut reasons: Vec<String> = Vec::new();
    for end in ends {
        let reason = end.reason.to_string();
        if !reasons.contains(&reason) {
            reasons.push(reason);
        }
    }
    for reason in reasons {
        let names: Vec<String> = ends
            .iter()
            .filter(|end| end.reason.to_string() == reason)
            .map(|end| format!("{}/{} session {}", end.fleet, end.robot, end.session))
            .collect();
        let more = match names.len() {
            n if n > 5 => format!(" and {} more", n - 5),
            _ => String::new(),
        };
        tracing::warn!(
            "end of {} session(s) not confirmed by the service ({reason}): {}{more}; closing \
             their publication caches anyway, frames not applied yet are lost",
            names.len(),
            names[..names.len().min(5)].join(", ")
        );
    }
}

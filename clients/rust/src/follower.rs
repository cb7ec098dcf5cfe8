//! What a robot publisher follows besides its own frames, on threads other than the caller's:
//! the service's reports about its sessions and the instances' liveliness tokens, into the
//! state it shares with the publisher.
//!
//! Invariants of this file:
//!
//! * Zenoh's callback only hands a report's payload to a bounded channel; the follower thread
//!   decodes it, fences it by epoch, updates the status and calls `on_error`. A
//!   `SESSION_CLOSED` about the current session becomes a flag the next `publish` acts on, so
//!   frames are never renumbered behind the caller's back.
//! * The instances' tokens are kept in the shared state; the publisher's owner ranks them for
//!   its partition (section 2a). The follower logs one warning when the robot becomes unserved
//!   (or still is 2 s after the start) and one info line when it is served again.
//! * After a `SESSION_CLOSED` for the current session, with `auto_new_session`, the follower
//!   asks the robot's state: another publisher's open session of the robot name (a holder)
//!   makes `publish` fail instead of starting a session that would close that one.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, RecvTimeoutError};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use zenoh::pubsub::Subscriber;
use zenoh::sample::{Sample, SampleKind};
use zenoh::{Session, Wait};

use crate::codec::decode;
use crate::error::{ClientError, ErrorCode};
use crate::messages::{Error, SessionState};
use crate::names::{keys, owner_and_standby, partition_of};
use crate::query::{current_states, get_all};

/// Error reports waiting for the follower thread; more are dropped and counted.
const INBOX_MAX: usize = 1000;
/// After this long without an owner since the publisher started, it warns once.
const UNSERVED_GRACE: Duration = Duration::from_secs(2);
/// How long the follower asks who holds the robot after a `SESSION_CLOSED`.
const HOLDER_QUERY: Duration = Duration::from_secs(1);

/// A callback for the service's reports about a robot's sessions.
pub type ErrorCallback = Box<dyn Fn(&Error) + Send + 'static>;

/// A publisher's session and numbering, what the service reported, the live instances.
pub(crate) struct State {
    pub(crate) session_id: String,
    pub(crate) next_seq: u64,
    pub(crate) frames_sent: u64,
    pub(crate) sessions: Vec<String>,
    pub(crate) errors: BTreeMap<String, u64>,
    pub(crate) last_error: Option<Error>,
    pub(crate) closed_report: bool,
    /// Another open session of this robot name the service holds (seen after a
    /// `SESSION_CLOSED`): `publish` does not start a new session over it.
    pub(crate) holder: Option<String>,
    pub(crate) highest_epoch: u64,
    pub(crate) stale: u64,
    pub(crate) live: BTreeSet<String>,
}

impl State {
    pub(crate) fn start_session(&mut self, session_id: String) {
        self.session_id = session_id.clone();
        self.sessions.push(session_id);
        self.next_seq = 0;
        self.closed_report = false;
        self.holder = None;
    }
}

/// What a robot publisher shares with its follower thread and Zenoh's callbacks.
pub(crate) struct Shared {
    pub(crate) state: Mutex<State>,
    pub(crate) live_changed: Condvar,
    /// Reports handed to the follower and reports it handled (`flush_errors`).
    pub(crate) inbox: Mutex<Inbox>,
    pub(crate) inbox_changed: Condvar,
    pub(crate) dropped: AtomicU64,
    pub(crate) stop: AtomicBool,
}

#[derive(Default)]
pub(crate) struct Inbox {
    pub(crate) received: u64,
    pub(crate) handled: u64,
}

impl Shared {
    /// The state of a publisher starting session `session_id`.
    pub(crate) fn new(session_id: String) -> Shared {
        Shared {
            state: Mutex::new(State {
                session_id: session_id.clone(),
                next_seq: 0,
                frames_sent: 0,
                sessions: vec![session_id],
                errors: BTreeMap::new(),
                last_error: None,
                closed_report: false,
                holder: None,
                highest_epoch: 0,
                stale: 0,
                live: BTreeSet::new(),
            }),
            live_changed: Condvar::new(),
            inbox: Mutex::new(Inbox::default()),
            inbox_changed: Condvar::new(),
            dropped: AtomicU64::new(0),
            stop: AtomicBool::new(false),
        }
    }

    pub(crate) fn lock(&self) -> MutexGuard<'_, State> {
        // A panic in on_error never holds this lock, so poisoning is not expected; recover.
        self.state
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    pub(crate) fn inbox(&self) -> MutexGuard<'_, Inbox> {
        self.inbox
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// Follow the robot's `errors` key: Zenoh's callback hands each report to a bounded channel,
/// and the follower thread returned handles it (and checks every 100 ms whether the robot is
/// served) until `shared.stop` is set or the subscriber is gone.
pub(crate) fn follow_errors(
    session: &Session,
    fleet: &str,
    robot: &str,
    shared: Arc<Shared>,
    auto_new_session: bool,
    on_error: Option<ErrorCallback>,
) -> Result<(Subscriber<()>, JoinHandle<()>), ClientError> {
    let (tx, rx) = sync_channel::<Vec<u8>>(INBOX_MAX);
    let counter = Arc::clone(&shared);
    let errors_sub = session
        .declare_subscriber(keys::errors(fleet, robot)?)
        .callback(move |sample: Sample| {
            // Counted under the inbox lock, so `handled` never runs ahead of it.
            let mut inbox = counter.inbox();
            match tx.try_send(sample.payload().to_bytes().into_owned()) {
                Ok(()) => inbox.received += 1,
                Err(_) => {
                    counter.dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
        })
        .wait()?;
    let label = format!("{fleet}/{robot}");
    let reports = Reports {
        label: label.clone(),
        partition: partition_of(fleet, robot),
        session: session.clone(),
        state_key: keys::state(fleet, robot)?,
        auto_new_session,
        on_error,
    };
    let follower = std::thread::Builder::new()
        .name(format!("lessmap-robot-{label}"))
        .spawn(move || {
            let mut served = Served::new(Instant::now() + UNSERVED_GRACE);
            loop {
                match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(payload) => {
                        handle_report(&shared, &reports, &payload);
                        shared.inbox().handled += 1;
                        shared.inbox_changed.notify_all();
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => return,
                }
                if shared.stop.load(Ordering::Relaxed) {
                    return;
                }
                served.check(&shared, &reports);
            }
        })
        .map_err(|err| ClientError::Connect(format!("cannot start a thread: {err}")))?;
    Ok((errors_sub, follower))
}

/// Follow the instances' liveliness tokens into `shared`'s live set: a liveliness subscriber
/// with history gives the live ones, then the changes.
pub(crate) fn follow_instances(
    session: &Session,
    shared: Arc<Shared>,
) -> Result<Subscriber<()>, ClientError> {
    let prefix = keys::instances().trim_end_matches('*').to_owned();
    let live_sub = session
        .liveliness()
        .declare_subscriber(keys::instances())
        .history(true)
        .callback(move |sample: Sample| {
            let key = sample.key_expr().as_str();
            if let Some(name) = key.strip_prefix(prefix.as_str()) {
                let mut state = shared.lock();
                if sample.kind() == SampleKind::Put {
                    state.live.insert(name.to_owned());
                } else {
                    state.live.remove(name);
                }
                shared.live_changed.notify_all();
            }
        })
        .wait()?;
    Ok(live_sub)
}

/// What the follower thread needs to handle the reports of one robot.
struct Reports {
    label: String,
    partition: u16,
    session: Session,
    state_key: String,
    auto_new_session: bool,
    on_error: Option<ErrorCallback>,
}

/// Whether the robot is served, as the follower last logged it: one warning when the robot
/// becomes unserved (or still is [`UNSERVED_GRACE`] after the start), one info line when it is
/// served again. The follower checks after every report and every 100 ms.
struct Served {
    owner: Option<String>,
    warned: bool,
    grace_until: Option<Instant>,
}

impl Served {
    fn new(grace_until: Instant) -> Served {
        Served {
            owner: None,
            warned: false,
            grace_until: Some(grace_until),
        }
    }

    fn check(&mut self, shared: &Shared, reports: &Reports) {
        let owner = {
            let state = shared.lock();
            let live: Vec<&String> = state.live.iter().collect();
            owner_and_standby(reports.partition, &live).0
        };
        let startup = self
            .grace_until
            .is_some_and(|until| Instant::now() >= until);
        if startup {
            self.grace_until = None;
        }
        let before = std::mem::replace(&mut self.owner, owner.clone());
        let (label, partition) = (&reports.label, reports.partition);
        match owner {
            None if !self.warned && (before.is_some() || startup) => {
                self.warned = true;
                tracing::warn!(
                    "{label}: no live lessmap instance owns partition {partition}: the robot is \
                     not served (its recent frames wait in the publisher's cache for the next \
                     owner)"
                );
            }
            Some(owner) if self.warned => {
                self.warned = false;
                tracing::info!("{label}: partition {partition} is served again, by {owner}");
            }
            Some(owner) if before.as_deref() != Some(owner.as_str()) => {
                tracing::debug!("{label}: partition {partition} owner {owner}");
            }
            _ => {}
        }
    }
}

/// Handle one report on the follower thread.
fn handle_report(shared: &Shared, reports: &Reports, payload: &[u8]) {
    let label = &reports.label;
    let error = match decode::<Error>(payload) {
        Ok(error) => error,
        Err(err) => {
            tracing::warn!("{label}: skipped an undecodable error report: {err}");
            return;
        }
    };
    let closes_current = {
        let mut state = shared.lock();
        if let Some(session) = &error.session {
            if !state.sessions.contains(session) {
                return; // about another publisher's session of this robot name
            }
        }
        if let Some(epoch) = error.epoch {
            if epoch < state.highest_epoch {
                state.stale += 1; // a deposed owner's late report
                return;
            }
            state.highest_epoch = epoch;
        }
        *state
            .errors
            .entry(error.code.as_str().to_owned())
            .or_insert(0) += 1;
        state.last_error = Some(error.clone());
        let current = state.session_id.clone();
        (error.code == ErrorCode::SessionClosed
            && error.session.as_deref() == Some(current.as_str())
            && !state.closed_report)
            .then_some(current)
    };
    tracing::warn!(
        "{label}: the service reported {} for session {:?} seq {:?}: {}",
        error.code,
        error.session,
        error.seq,
        error.detail
    );
    if let Some(current) = closes_current {
        // Starting a new session would close any other open session of this robot name:
        // never fight another publisher for it.
        let holder = if reports.auto_new_session {
            other_holder(shared, reports, &current)
        } else {
            None
        };
        let mut state = shared.lock();
        if state.session_id == current && !state.closed_report {
            state.closed_report = true;
            state.holder = holder;
        }
    }
    if let Some(callback) = &reports.on_error {
        if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| callback(&error))).is_err() {
            tracing::error!("{label}: on_error panicked");
        }
    }
}

/// Another open session the service holds for this robot name, if any (the current owner's
/// answer only; a failed query or no answer: none).
fn other_holder(shared: &Shared, reports: &Reports, current: &str) -> Option<String> {
    let found = get_all::<SessionState>(&reports.session, &reports.state_key, HOLDER_QUERY).ok()?;
    let state = current_states(found).into_iter().next()?;
    let ours = shared.lock().sessions.contains(&state.session);
    (state.open && state.session != current && !ours).then_some(state.session)
}

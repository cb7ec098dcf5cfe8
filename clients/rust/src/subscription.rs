//! One subscription: its own bounded queue, read with `recv`.
//!
//! Invariants of this file:
//!
//! * Zenoh's callback only copies the payload into this subscription's bounded channel and
//!   returns: no decoding, no logging, no blocking, no Zenoh call. When `maxsize` events wait
//!   unread, a new one is dropped and counted (`dropped`); the oldest stay, so a slow reader
//!   sees an unbroken prefix.
//! * Decoding, fencing and de-duplication happen on the reader's thread, in `recv`.
//! * Fencing (contract section 2a): per robot, the highest `epoch` seen on a `Transition` or
//!   an `Error` is kept, and an event with a lower one (a deposed owner's late event) is
//!   dropped (`dropped_stale`), before transitions are de-duplicated by identity
//!   `(fleet, robot, session, incarnation, closed.id)` (`duplicates`).

use std::collections::{HashMap, HashSet, VecDeque};
use std::marker::PhantomData;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// What a transition is identified by: (fleet, robot, session, incarnation, closed id).
type Identity = (String, String, String, u64, u64);

use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};
use zenoh_ext::{AdvancedSubscriber, AdvancedSubscriberBuilderExt, HistoryConfig, RecoveryConfig};

use crate::codec::decode;
use crate::error::ClientError;
use crate::messages::{Error, Message, Transition};

/// Events a subscription buffers by default before it drops new ones.
pub const DEFAULT_MAXSIZE: usize = 10_000;
/// Transition identities remembered for de-duplication.
const SEEN_KEPT: usize = 100_000;
/// Robots whose highest epoch is remembered for fencing.
const EPOCHS_KEPT: usize = 100_000;

/// An event a subscription delivers: fenced by epoch, transitions de-duplicated.
pub trait Event: Message {
    /// `(fleet, robot, epoch)` when the event is attributable to a robot's owner.
    fn fence(&self) -> Option<(&str, &str, u64)>;

    /// The identity repeats are dropped by, if the event has one.
    fn identity(&self) -> Option<Identity> {
        None
    }
}

impl Event for Transition {
    fn fence(&self) -> Option<(&str, &str, u64)> {
        Some((&self.fleet, &self.robot, self.epoch))
    }

    fn identity(&self) -> Option<Identity> {
        Some((
            self.fleet.clone(),
            self.robot.clone(),
            self.session.clone(),
            self.incarnation,
            self.closed.id,
        ))
    }
}

impl Event for Error {
    fn fence(&self) -> Option<(&str, &str, u64)> {
        // An Error with a null epoch names no robot's owner and is never fenced.
        match (&self.fleet, &self.robot, self.epoch) {
            (Some(fleet), Some(robot), Some(epoch)) => Some((fleet, robot, epoch)),
            _ => None,
        }
    }
}

enum Entity {
    Plain(Subscriber<()>),
    Advanced(AdvancedSubscriber<()>),
}

/// The events of one declaration, made by `Connection::subscribe_transitions` and its
/// siblings. Dropping it undeclares the subscriber.
pub struct Subscription<T> {
    rx: Receiver<Vec<u8>>,
    dropped: Arc<AtomicU64>,
    entity: Option<Entity>,
    epochs: HashMap<(String, String), u64>,
    epoch_order: VecDeque<(String, String)>,
    seen: HashSet<Identity>,
    seen_order: VecDeque<Identity>,
    undecodable: u64,
    duplicates: u64,
    dropped_stale: u64,
    _event: PhantomData<T>,
}

impl<T: Event> Subscription<T> {
    fn channel(maxsize: usize) -> (impl Fn(Sample) + Send + Sync + 'static, Self) {
        let (tx, rx) = sync_channel::<Vec<u8>>(maxsize.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        let counter = Arc::clone(&dropped);
        // Zenoh's thread: copy, hand over, return.
        let deliver = move |sample: Sample| {
            if tx
                .try_send(sample.payload().to_bytes().into_owned())
                .is_err()
            {
                counter.fetch_add(1, Ordering::Relaxed);
            }
        };
        let sub = Subscription {
            rx,
            dropped,
            entity: None,
            epochs: HashMap::new(),
            epoch_order: VecDeque::new(),
            seen: HashSet::new(),
            seen_order: VecDeque::new(),
            undecodable: 0,
            duplicates: 0,
            dropped_stale: 0,
            _event: PhantomData,
        };
        (deliver, sub)
    }

    /// A live-only subscription.
    pub(crate) fn plain(
        session: &Session,
        key: String,
        maxsize: usize,
    ) -> Result<Self, ClientError> {
        let (deliver, mut sub) = Self::channel(maxsize);
        let entity = session.declare_subscriber(key).callback(deliver).wait()?;
        sub.entity = Some(Entity::Plain(entity));
        Ok(sub)
    }

    /// A subscription that recovers recent history on joining and fetches samples lost in
    /// transit from the publishers' caches (zenoh-ext `AdvancedSubscriber`).
    pub(crate) fn advanced(
        session: &Session,
        key: String,
        history: Option<usize>,
        maxsize: usize,
    ) -> Result<Self, ClientError> {
        let (deliver, mut sub) = Self::channel(maxsize);
        let mut builder = session
            .declare_subscriber(key)
            .callback(deliver)
            // Gaps in a publisher's sequence are fetched from its cache, so a sample lost on
            // the way (or raced by the history query) still arrives, in order.
            .recovery(RecoveryConfig::default().heartbeat());
        if let Some(depth) = history.filter(|depth| *depth > 0) {
            builder = builder.history(
                HistoryConfig::default()
                    .detect_late_publishers()
                    .max_samples(depth),
            );
        }
        sub.entity = Some(Entity::Advanced(builder.wait()?));
        Ok(sub)
    }

    /// The next event, or `None` after `timeout` (or once the subscription is closed).
    pub fn recv(&mut self, timeout: Duration) -> Option<T> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let payload = match self.rx.recv_timeout(left) {
                Ok(payload) => payload,
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return None,
            };
            if let Some(event) = self.accept(&payload) {
                return Some(event);
            }
        }
    }

    /// The next event if one is waiting (never blocks).
    pub fn try_recv(&mut self) -> Option<T> {
        while let Ok(payload) = self.rx.try_recv() {
            if let Some(event) = self.accept(&payload) {
                return Some(event);
            }
        }
        None
    }

    fn accept(&mut self, payload: &[u8]) -> Option<T> {
        let event = match decode::<T>(payload) {
            Ok(event) => event,
            Err(err) => {
                self.undecodable += 1;
                tracing::warn!("skipped an undecodable {}: {err}", T::TYPE);
                return None;
            }
        };
        if self.is_stale(&event) {
            self.dropped_stale += 1;
            return None;
        }
        if let Some(identity) = event.identity() {
            if !self.seen.insert(identity.clone()) {
                self.duplicates += 1;
                return None;
            }
            self.seen_order.push_back(identity);
            if self.seen_order.len() > SEEN_KEPT {
                if let Some(old) = self.seen_order.pop_front() {
                    self.seen.remove(&old);
                }
            }
        }
        Some(event)
    }

    fn is_stale(&mut self, event: &T) -> bool {
        let Some((fleet, robot, epoch)) = event.fence() else {
            return false;
        };
        let robot = (fleet.to_owned(), robot.to_owned());
        match self.epochs.get_mut(&robot) {
            Some(highest) if epoch < *highest => return true,
            Some(highest) => *highest = epoch,
            None => {
                self.epochs.insert(robot.clone(), epoch);
                self.epoch_order.push_back(robot);
                if self.epoch_order.len() > EPOCHS_KEPT {
                    if let Some(old) = self.epoch_order.pop_front() {
                        self.epochs.remove(&old);
                    }
                }
            }
        }
        false
    }

    /// Events dropped because `maxsize` events were waiting unread.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Payloads that were not valid messages (skipped).
    pub fn undecodable(&self) -> u64 {
        self.undecodable
    }

    /// Transitions skipped as repeats of one already delivered.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }

    /// Events skipped for an epoch below the highest seen for their robot.
    pub fn dropped_stale(&self) -> u64 {
        self.dropped_stale
    }

    /// Stop receiving: undeclare the subscriber. Events already queued can still be read.
    pub fn close(&mut self) -> Result<(), ClientError> {
        match self.entity.take() {
            Some(Entity::Plain(sub)) => sub.undeclare().wait()?,
            Some(Entity::Advanced(sub)) => sub.undeclare().wait()?,
            None => {}
        }
        Ok(())
    }
}

impl<T> Drop for Subscription<T> {
    fn drop(&mut self) {
        // Advanced entities must be undeclared before their session closes.
        match self.entity.take() {
            Some(Entity::Plain(sub)) => drop(sub.undeclare().wait()),
            Some(Entity::Advanced(sub)) => drop(sub.undeclare().wait()),
            None => {}
        }
    }
}

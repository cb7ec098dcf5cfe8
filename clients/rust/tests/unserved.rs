//! A robot publisher logs when nobody serves it and when somebody does again.
//!
//! On real Zenoh sessions on loopback: the test's router session plays the service instance
//! by its liveliness token alone. The crate's log lines are captured by a minimal `tracing`
//! subscriber installed for this test binary (one test here: the subscriber is global).

mod common;

use common::{router, wait_until, WAIT};

use std::fmt;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use lessmap_client::{keys, Connection};
use tracing::field::{Field, Visit};
use tracing::span::{Attributes, Id, Record};
use tracing::{Event, Level, Metadata, Subscriber};
use zenoh::Wait;

static LINES: Mutex<Vec<(Level, String)>> = Mutex::new(Vec::new());

/// Keeps the level and message of every event of this crate.
struct Capture;

struct Message(String);

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

impl Subscriber for Capture {
    fn enabled(&self, metadata: &Metadata<'_>) -> bool {
        metadata.target().starts_with("lessmap_client")
    }

    fn new_span(&self, _: &Attributes<'_>) -> Id {
        Id::from_u64(1)
    }

    fn record(&self, _: &Id, _: &Record<'_>) {}

    fn record_follows_from(&self, _: &Id, _: &Id) {}

    fn event(&self, event: &Event<'_>) {
        let mut message = Message(String::new());
        event.record(&mut message);
        let level = *event.metadata().level();
        LINES.lock().unwrap().push((level, message.0));
    }

    fn enter(&self, _: &Id) {}

    fn exit(&self, _: &Id) {}
}

/// Lines at `level` that contain every one of `parts`.
fn lines(level: Level, parts: &[&str]) -> usize {
    LINES
        .lock()
        .unwrap()
        .iter()
        .filter(|(at, text)| *at == level && parts.iter().all(|part| text.contains(part)))
        .count()
}

#[test]
fn robot_warns_once_when_unserved_and_tells_when_served_again() {
    tracing::subscriber::set_global_default(Capture).expect("the only subscriber");
    let (service, endpoint) = router(); // no instance yet
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let started = Instant::now();
    let robot = conn.robot("fleet", "u1").unwrap();
    let unserved = ["fleet/u1", "not served"];
    let served_again = ["fleet/u1", "served again, by fake-a"];

    // Nobody ever served it: one warning, after the 2 s grace from the start.
    wait_until("the unserved warning", || {
        lines(Level::WARN, &unserved) == 1
    });
    assert!(started.elapsed() >= Duration::from_secs(2));
    assert_eq!(robot.status().owner, None);
    // Several checks of the follower (every 0.1 s) while still unserved: none may warn again.
    // (The pause only gives a repeated warning the chance to show; it passes at any speed.)
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(lines(Level::WARN, &unserved), 1);

    // An instance appears: one info line; the warning was not repeated meanwhile.
    let token = service
        .liveliness()
        .declare_token(keys::instance_token("fake-a").unwrap())
        .wait()
        .unwrap();
    wait_until("the served-again line", || {
        lines(Level::INFO, &served_again) == 1
    });
    assert_eq!(lines(Level::WARN, &unserved), 1);
    assert_eq!(robot.status().owner.as_deref(), Some("fake-a"));

    // It leaves: warned again, at once (no grace after a loss).
    token.undeclare().wait().unwrap();
    wait_until("the second unserved warning", || {
        lines(Level::WARN, &unserved) == 2
    });
    assert_eq!(lines(Level::INFO, &served_again), 1);

    robot.close_within(Duration::ZERO).unwrap();
    conn.close().unwrap();
    service.close().wait().unwrap();
}

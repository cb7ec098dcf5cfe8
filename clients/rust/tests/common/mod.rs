//! Helpers the loopback test binaries share: a router of their own, bounded waits.
//!
//! Each file under `tests/` is its own crate and uses only some of these.
#![allow(dead_code)]

use std::net::TcpListener;
use std::time::{Duration, Instant};

use zenoh::{Session, Wait};

/// How long a test waits for anything before it fails.
pub const WAIT: Duration = Duration::from_secs(10);

/// A router on a free loopback port, and its endpoint.
pub fn router() -> (Session, String) {
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|listener| listener.local_addr())
        .expect("a free port")
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"router\"").unwrap();
    config
        .insert_json5("listen/endpoints", &format!("[\"{endpoint}\"]"))
        .unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    (zenoh::open(config).wait().expect("router"), endpoint)
}

/// Poll `done` until it holds; panic naming `what` after `WAIT`.
pub fn wait_until(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + WAIT;
    while !done() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Assert that `took` lies in `[min, max)`.
pub fn assert_took(what: &str, took: Duration, min: Duration, max: Duration) {
    assert!(
        took >= min && took < max,
        "{what} took {took:?}, expected {min:?} to {max:?}"
    );
}

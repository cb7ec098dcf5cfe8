//! `close_all` on real Zenoh sessions on loopback: every end first, then one shared wait.
//!
//! The test plays the service with a Zenoh router session of its own (a liveliness token and a
//! `SessionState` queryable for every robot, which records the keys it is asked on), as
//! `tests/loopback.rs` does; `tests/rust/` in the repository runs `close_all` against a real
//! `lessmap serve`.

mod common;

use common::{assert_took, router, WAIT};

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use lessmap_client::codec::{decode_inbound, encode, Inbound};
use lessmap_client::{
    close_all, keys, Connection, Method, RobotOptions, RobotPublisher, SessionState, SubmapSummary,
    UnconfirmedReason,
};
use zenoh::query::Queryable;
use zenoh::{Session, Wait};

/// The `SessionState` a fake service answers for `fleet`/`robot`'s `session`.
fn session_state(
    fleet: &str,
    robot: &str,
    session: &str,
    open: bool,
    last_seq: u64,
) -> SessionState {
    SessionState {
        fleet: fleet.into(),
        robot: robot.into(),
        session: session.into(),
        incarnation: 0,
        instance: "fake-a".into(),
        epoch: 1,
        open,
        last_seq: Some(last_seq),
        frames_applied: last_seq + 1,
        frames_duplicate: 0,
        frames_missing: 0,
        frames_rejected: 0,
        transitions: 0,
        method: Method::Paper,
        current_area: 0,
        current_submap: SubmapSummary {
            id: 0,
            first_seq: 0,
            last_seq,
            frame_count: last_seq + 1,
            features: vec![],
        },
        closed_submaps: vec![],
        nodes: 1,
        edges: 0,
    }
}

type States = Arc<Mutex<BTreeMap<(String, String), SessionState>>>;

/// A fake service instance: its token and a `SessionState` queryable for every robot of every
/// fleet, answering from `states` (one reply per robot the query's key matches) and recording
/// the key of every query.
struct FakeService {
    states: States,
    asked: Arc<Mutex<Vec<String>>>,
    _queryable: Queryable<()>,
    _token: zenoh::liveliness::LivelinessToken,
}

impl FakeService {
    fn start(service: &Session) -> FakeService {
        let states: States = Arc::default();
        let asked: Arc<Mutex<Vec<String>>> = Arc::default();
        let (answer, record) = (Arc::clone(&states), Arc::clone(&asked));
        let queryable = service
            .declare_queryable(keys::state("*", "*").unwrap())
            .callback(move |query| {
                let key = query.key_expr().as_str().to_owned();
                record.lock().unwrap().push(key.clone());
                let chunks: Vec<&str> = key.split('/').collect();
                let (fleet, robot) = (chunks[2], chunks[3]);
                let replies: Vec<SessionState> = answer
                    .lock()
                    .unwrap()
                    .values()
                    .filter(|s| {
                        (s.fleet == fleet || fleet == "*") && (s.robot == robot || robot == "*")
                    })
                    .cloned()
                    .collect();
                for state in replies {
                    let reply_key = keys::state(&state.fleet, &state.robot).unwrap();
                    query.reply(reply_key, encode(&state)).wait().unwrap();
                }
            })
            .wait()
            .unwrap();
        let token = service
            .liveliness()
            .declare_token(keys::instance_token("fake-a").unwrap())
            .wait()
            .unwrap();
        FakeService {
            states,
            asked,
            _queryable: queryable,
            _token: token,
        }
    }

    fn set(&self, state: SessionState) {
        let robot = (state.fleet.clone(), state.robot.clone());
        self.states.lock().unwrap().insert(robot, state);
    }

    fn asked(&self) -> Vec<String> {
        self.asked.lock().unwrap().clone()
    }
}

/// Robots `prefix0..prefixN` of `fleet`, each with `frames` frames published.
fn robots(
    conn: &Connection,
    fleet: &str,
    prefix: &str,
    n: usize,
    frames: u64,
) -> Vec<RobotPublisher> {
    (0..n)
        .map(|i| {
            let robot = conn.robot(fleet, &format!("{prefix}{i}")).unwrap();
            for seq in 0..frames {
                assert_eq!(robot.publish(&[seq, seq + 1]).unwrap(), seq);
            }
            robot
        })
        .collect()
}

/// `(fleet, robot, session, last seq)` of every `SessionEnd` received so far.
fn ends_received(
    frames: &zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    ends: &mut Vec<(String, String, String, Option<u64>)>,
) {
    while let Ok(Some(sample)) = frames.try_recv() {
        let chunks: Vec<String> = sample
            .key_expr()
            .as_str()
            .split('/')
            .map(str::to_owned)
            .collect();
        if let Ok(Inbound::SessionEnd(end)) =
            decode_inbound(&sample.payload().to_bytes(), &Default::default())
        {
            ends.push((
                chunks[2].clone(),
                chunks[3].clone(),
                end.session,
                end.last_seq,
            ));
        }
    }
}

#[test]
fn close_all_sends_every_end_then_waits_once_with_one_query_per_fleet() {
    let (service, endpoint) = router();
    let frames = service
        .declare_subscriber(keys::frames("*", "*").unwrap())
        .wait()
        .unwrap();
    let fake = FakeService::start(&service);
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    // Six robots of one fleet and one of another, three frames each, on one Zenoh session.
    let mut all = robots(&conn, "fa", "r", 6, 3);
    all.extend(robots(&conn, "fb", "solo", 1, 3));
    let sessions: Vec<(String, String, String)> = all
        .iter()
        .map(|r| (r.fleet().to_owned(), r.robot().to_owned(), r.session_id()))
        .collect();
    // The service has applied 2 of 3 frames of each: every end waits.
    for (fleet, robot, session) in &sessions {
        fake.set(session_state(fleet, robot, session, true, 1));
    }
    let closer = {
        let (states, sessions) = (Arc::clone(&fake.states), sessions.clone());
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(400));
            // Every session closed at once, under one lock: a reply holds all or none.
            let mut states = states.lock().unwrap();
            for (fleet, robot, session) in &sessions {
                let closed = session_state(fleet, robot, session, false, 2);
                states.insert((fleet.clone(), robot.clone()), closed);
            }
        })
    };
    let timeout = Duration::from_secs(5);
    let started = Instant::now();
    let report = close_all(all, timeout);
    let took = started.elapsed();
    closer.join().unwrap();
    // Not before the service closed them, and well within the timeout.
    assert_took(
        "close_all of 7 robots",
        took,
        Duration::from_millis(400),
        timeout,
    );
    assert!(report.is_clean(), "{report:?}");
    assert_eq!(report.closed, 7);
    // Every end went out once, with the last seq, before any wait.
    let mut ends = Vec::new();
    let deadline = Instant::now() + WAIT;
    while ends.len() < sessions.len() && Instant::now() < deadline {
        ends_received(&frames, &mut ends);
        std::thread::sleep(Duration::from_millis(20));
    }
    let got: BTreeSet<_> = ends.iter().cloned().collect();
    let expected: BTreeSet<_> = sessions
        .iter()
        .map(|(fleet, robot, session)| (fleet.clone(), robot.clone(), session.clone(), Some(2)))
        .collect();
    assert_eq!(ends.len(), sessions.len(), "{ends:?}");
    assert_eq!(got, expected);
    // One query per fleet and poll: the wildcard for the six, the robot's key for the one.
    let asked = fake.asked();
    let kinds: BTreeSet<&str> = asked.iter().map(String::as_str).collect();
    let wanted: BTreeSet<String> = [keys::state("fa", "*"), keys::state("fb", "solo0")]
        .into_iter()
        .map(Result::unwrap)
        .collect();
    assert_eq!(
        kinds,
        wanted.iter().map(String::as_str).collect(),
        "{asked:?}"
    );
    // Each poll asks each fleet still waiting once. The fake closes every session at one
    // moment, which can fall between a poll's two queries: then one fleet is asked once
    // more than the other (1 run in 6 here), never more.
    let per_fleet = |key: &str| asked.iter().filter(|k| *k == key).count();
    let (six, one) = (
        per_fleet(&keys::state("fa", "*").unwrap()),
        per_fleet(&keys::state("fb", "solo0").unwrap()),
    );
    assert!(six.abs_diff(one) <= 1, "{asked:?}");
    conn.close().unwrap();
    drop(fake);
    drop(frames);
    service.close().wait().unwrap();
}

#[test]
fn close_all_reports_the_ends_left_unconfirmed_in_order() {
    let (service, endpoint) = router();
    let fake = FakeService::start(&service);
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let all = robots(&conn, "fleet", "u", 3, 2);
    let sessions: Vec<String> = all.iter().map(RobotPublisher::session_id).collect();
    // The service answers for u1 only (closed); u0 and u2 are never confirmed (a take-over
    // that does not finish).
    fake.set(session_state("fleet", "u1", &sessions[1], false, 1));
    let timeout = Duration::from_millis(600);
    let started = Instant::now();
    let report = close_all(all, timeout);
    assert_took(
        "close_all with two ends never confirmed",
        started.elapsed(),
        timeout,
        timeout + Duration::from_secs(3),
    );
    assert_eq!(report.closed, 3);
    assert!(report.failures.is_empty(), "{report:?}");
    let left: Vec<(&str, &str, u64, &UnconfirmedReason)> = report
        .unconfirmed
        .iter()
        .map(|end| {
            (
                end.robot.as_str(),
                end.session.as_str(),
                end.last_seq,
                &end.reason,
            )
        })
        .collect();
    let timed_out = UnconfirmedReason::TimedOut(timeout);
    assert_eq!(
        left,
        [
            ("u0", sessions[0].as_str(), 1, &timed_out),
            ("u2", sessions[2].as_str(), 1, &timed_out)
        ]
    );
    assert!(!report.is_clean());
    conn.close().unwrap();
    drop(fake);
    service.close().wait().unwrap();
}

#[test]
fn close_all_without_a_service_returns_at_once_with_every_end_unconfirmed() {
    let (service, endpoint) = router(); // a router, no lessmap instance
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let all = robots(&conn, "fleet", "n", 4, 2);
    let sessions: Vec<String> = all.iter().map(RobotPublisher::session_id).collect();
    let timeout = Duration::from_secs(5);
    let started = Instant::now();
    let report = close_all(all, timeout);
    // One liveliness query (at most 0.5 s) after the first pause, not the timeout.
    assert_took(
        "close_all with no service",
        started.elapsed(),
        Duration::ZERO,
        Duration::from_secs(3),
    );
    assert_eq!(report.closed, 4);
    assert!(report.failures.is_empty(), "{report:?}");
    let left: Vec<(String, String, u64, UnconfirmedReason)> = report
        .unconfirmed
        .into_iter()
        .map(|end| (end.robot, end.session, end.last_seq, end.reason))
        .collect();
    let expected: Vec<(String, String, u64, UnconfirmedReason)> = sessions
        .iter()
        .enumerate()
        .map(|(i, session)| {
            (
                format!("n{i}"),
                session.clone(),
                1,
                UnconfirmedReason::NoLiveInstance,
            )
        })
        .collect();
    assert_eq!(left, expected);
    conn.close().unwrap();
    service.close().wait().unwrap();
}

#[test]
fn close_all_needs_no_wait_without_frames_nor_with_a_zero_timeout() {
    let (service, endpoint) = router();
    let fake = FakeService::start(&service); // alive, but answers for nobody
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();

    // Nothing to close.
    let report = close_all(Vec::new(), Duration::from_secs(5));
    assert_eq!((report.closed, report.is_clean()), (0, true));

    // No frame sent: the ends need no confirmation.
    let quiet = robots(&conn, "fleet", "q", 2, 0);
    let started = Instant::now();
    let report = close_all(quiet, Duration::from_secs(5));
    assert_took(
        "close_all without frames",
        started.elapsed(),
        Duration::ZERO,
        Duration::from_secs(3),
    );
    assert_eq!((report.closed, report.is_clean()), (2, true));

    // A zero timeout: the ends, then the releases; nothing was waited for, nothing reported.
    let options = || RobotOptions {
        close_timeout: Duration::from_secs(30), // not the one close_all uses
        ..RobotOptions::default()
    };
    let busy: Vec<RobotPublisher> = (0..2)
        .map(|i| {
            let robot = conn
                .robot_with("fleet", &format!("z{i}"), options())
                .unwrap();
            robot.publish(&[1]).unwrap();
            robot
        })
        .collect();
    let started = Instant::now();
    let report = close_all(busy, Duration::ZERO);
    assert_took(
        "close_all with a zero timeout",
        started.elapsed(),
        Duration::ZERO,
        Duration::from_secs(3),
    );
    assert_eq!((report.closed, report.is_clean()), (2, true));
    assert!(fake.asked().is_empty(), "{:?}", fake.asked());
    conn.close().unwrap();
    drop(fake);
    service.close().wait().unwrap();
}

#[test]
fn close_all_on_a_closed_network_reports_failures_without_panicking() {
    let (service, endpoint) = router();
    let fake = FakeService::start(&service);
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let all = robots(&conn, "fleet", "c", 2, 2);
    conn.close().unwrap(); // the robots' Zenoh session goes with it
    let started = Instant::now();
    let report = close_all(all, Duration::from_secs(5));
    assert_took(
        "close_all on a closed session",
        started.elapsed(),
        Duration::ZERO,
        Duration::from_secs(3),
    );
    assert_eq!(report.closed, 2);
    // The ends could not be sent: nothing to confirm, and each robot named in the failures.
    assert!(report.unconfirmed.is_empty(), "{report:?}");
    let named: BTreeSet<&str> = report.failures.iter().map(|f| f.robot.as_str()).collect();
    assert_eq!(named, BTreeSet::from(["c0", "c1"]), "{report:?}");
    drop(fake);
    service.close().wait().unwrap();
}

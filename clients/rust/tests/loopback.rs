//! The robot publisher, subscriptions and queries on real Zenoh sessions on loopback.
//!
//! The test plays the service with a Zenoh router session of its own (a liveliness token,
//! `Health`, `SessionState` and `AreaGraph` queryables, puts on the errors and transitions
//! keys), so the client's own rules are checked without a lessmap service: numbering, session
//! ends, a new session after `SESSION_CLOSED`, epoch fencing, de-duplication, highest epoch of
//! replies, a close that waits for the service to confirm the end.

mod common;

use common::{assert_took, router, wait_until, WAIT};

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use lessmap_client::codec::{decode_inbound, encode, Inbound};
use lessmap_client::{
    keys, partition_of, AreaGraph, AreaNode, ClientError, Connection, Error, ErrorCode, Health,
    Method, Passage, Reason, RobotOptions, SessionState, SubmapSummary, Transition,
};
use zenoh::{Session, Wait};

fn summary(id: u64) -> SubmapSummary {
    SubmapSummary {
        id,
        first_seq: id * 10,
        last_seq: id * 10 + 9,
        frame_count: 10,
        features: vec![id],
    }
}

fn transition(fleet: &str, robot: &str, closed: u64, epoch: u64) -> Transition {
    Transition {
        fleet: fleet.into(),
        robot: robot.into(),
        session: "s1".into(),
        incarnation: 0,
        seq: closed * 10 + 10,
        boundary_seq: closed * 10 + 10,
        stamp_s: 1.0,
        reason: Reason::Spectral,
        ncut: Some(0.1),
        lambda2: Some(0.05),
        closed: summary(closed),
        opened: summary(closed + 1),
        boundary_features: vec![],
        area: closed + 1,
        left_area: closed,
        revisit: false,
        batch_frames: 1,
        instance: "fake-a".into(),
        partition: partition_of(fleet, robot),
        epoch,
    }
}

fn report(session: &str, code: ErrorCode, epoch: u64) -> Error {
    Error {
        fleet: Some("fleet".into()),
        robot: Some("r1".into()),
        session: Some(session.into()),
        code,
        detail: "from the test".into(),
        seq: None,
        stamp_s: 1.0,
        instance: "fake-a".into(),
        epoch: Some(epoch),
    }
}

#[test]
fn robot_numbers_frames_follows_its_errors_and_ends_its_sessions() {
    let (service, endpoint) = router();
    let (fleet, name) = ("fleet", "r1");
    let partition = partition_of(fleet, name);
    let frames = service
        .declare_subscriber(keys::frames(fleet, name).unwrap())
        .wait()
        .unwrap();
    let _token = service
        .liveliness()
        .declare_token(keys::instance_token("fake-a").unwrap())
        .wait()
        .unwrap();
    let _health = service
        .declare_queryable(keys::health("fake-a").unwrap())
        .callback(move |query| {
            let health = Health {
                instance: "fake-a".into(),
                version: "test".into(),
                sessions: 0,
                uptime_s: 1.0,
                frames_applied: 0,
                partitions: vec![partition],
                standby: vec![],
                queue_depth: 0,
                lag_s: 0.0,
            };
            query
                .reply(query.key_expr().clone(), encode(&health))
                .wait()
                .unwrap();
        })
        .wait()
        .unwrap();

    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let robot = conn.robot(fleet, name).unwrap();
    assert!(robot.wait_for_service(WAIT).unwrap());
    assert_eq!(robot.status().owner.as_deref(), Some("fake-a"));
    assert_eq!(robot.partition(), partition);
    let first = robot.session_id();
    assert_eq!(robot.publish(&[1, 2, 3]).unwrap(), 0);
    assert_eq!(robot.publish(&[3, 4]).unwrap(), 1);
    let mut received = Vec::new();
    let mut take = |n: usize| {
        while received.len() < n {
            let sample = frames.recv_timeout(WAIT).unwrap().expect("a frame in time");
            received
                .push(decode_inbound(&sample.payload().to_bytes(), &Default::default()).unwrap());
        }
        received.clone()
    };
    let got = take(2);
    assert!(
        matches!(&got[0], Inbound::Frame(f) if f.seq == 0 && f.session == first && f.features == [1, 2, 3])
    );
    assert!(matches!(&got[1], Inbound::Frame(f) if f.seq == 1 && f.session == first));

    // The service closes the session: the next frame opens a new one, numbered from 0.
    let errors_key = keys::errors(fleet, name).unwrap();
    service
        .put(
            &errors_key,
            encode(&report(&first, ErrorCode::SessionClosed, 5)),
        )
        .wait()
        .unwrap();
    wait_until("the robot to see SESSION_CLOSED", || {
        robot.status().closed_by_service
    });
    assert_eq!(robot.publish(&[5]).unwrap(), 0);
    let second = robot.session_id();
    assert_ne!(second, first);
    let got = take(3);
    assert!(matches!(&got[2], Inbound::Frame(f) if f.seq == 0 && f.session == second));
    let status = robot.status();
    assert_eq!(
        (status.sessions, status.count(ErrorCode::SessionClosed)),
        (2, 1)
    );

    // A deposed owner's late report (lower epoch) changes nothing.
    service
        .put(
            &errors_key,
            encode(&report(&second, ErrorCode::SessionClosed, 4)),
        )
        .wait()
        .unwrap();
    wait_until("the stale report", || robot.status().reports_stale == 1);
    assert!(!robot.status().closed_by_service);

    // No `SessionState` queryable here: close without waiting for a confirmation (tested in
    // robot_close_keeps_the_cache_until_the_service_confirms_the_end).
    robot.close_within(Duration::ZERO).unwrap();
    let got = take(4);
    assert!(
        matches!(&got[3], Inbound::SessionEnd(e) if e.session == second && e.last_seq == Some(0))
    );
    conn.close().unwrap();
    drop(frames);
    service.close().wait().unwrap();
}

#[test]
fn subscription_fences_deduplicates_and_queries_keep_the_highest_epoch() {
    let (service, endpoint) = router();
    let key = keys::transitions("fleet", "r2").unwrap();
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let mut sub = conn.subscribe_transitions("fleet", "*", None).unwrap();
    let publisher = service.declare_publisher(key).wait().unwrap();
    wait_until("the subscription to match", || {
        publisher.matching_status().wait().unwrap().matching()
    });
    for (closed, epoch) in [(0, 5), (0, 5), (1, 3), (1, 5)] {
        publisher
            .put(encode(&transition("fleet", "r2", closed, epoch)))
            .wait()
            .unwrap();
    }
    publisher.put(b"not msgpack".to_vec()).wait().unwrap();
    publisher
        .put(encode(&transition("fleet", "r2", 2, 6)))
        .wait()
        .unwrap();
    let got: Vec<(u64, u64)> = (0..3)
        .map(|_| sub.recv(WAIT).expect("a transition in time"))
        .map(|t| (t.closed.id, t.epoch))
        .collect();
    assert_eq!(got, [(0, 5), (1, 5), (2, 6)]);
    assert_eq!(
        (sub.duplicates(), sub.dropped_stale(), sub.undecodable()),
        (1, 1, 1)
    );

    // Two instances answer for one robot (a hand-over): the highest epoch is current.
    let state = |epoch: u64, applied: u64| SessionState {
        instance: format!("i{epoch}"),
        epoch,
        ..session_state("r2", "s1", true, applied - 1)
    };
    let mut queryables = Vec::new();
    for (epoch, applied) in [(7, 10), (3, 90)] {
        let reply = encode(&state(epoch, applied));
        queryables.push(
            service
                .declare_queryable(keys::state("fleet", "r2").unwrap())
                .callback(move |query| {
                    query
                        .reply(query.key_expr().clone(), reply.clone())
                        .wait()
                        .unwrap();
                })
                .wait()
                .unwrap(),
        );
    }
    wait_until("both queryables to answer", || {
        let replies = service
            .get(keys::state("fleet", "r2").unwrap())
            .target(zenoh::query::QueryTarget::All)
            .consolidation(zenoh::query::ConsolidationMode::None)
            .timeout(Duration::from_secs(2))
            .wait()
            .unwrap();
        replies
            .iter()
            .filter(|reply| reply.result().is_ok())
            .count()
            == 2
    });
    let current = conn.state("fleet", "r2", Duration::from_secs(2)).unwrap();
    // The higher epoch wins over more frames applied.
    assert_eq!(
        current.map(|s| (s.epoch, s.instance)),
        Some((7, "i7".to_owned()))
    );
    drop(sub);
    drop(queryables);
    conn.close().unwrap();
    service.close().wait().unwrap();
}

/// The `SessionState` a fake service answers for `robot`'s `session`.
fn session_state(robot: &str, session: &str, open: bool, last_seq: u64) -> SessionState {
    SessionState {
        fleet: "fleet".into(),
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
        current_submap: summary(0),
        closed_submaps: vec![],
        nodes: 1,
        edges: 0,
    }
}

#[test]
fn robot_close_keeps_the_cache_until_the_service_confirms_the_end() {
    let (service, endpoint) = router();
    let fleet = "fleet";
    let frames = service
        .declare_subscriber(keys::frames(fleet, "*").unwrap())
        .wait()
        .unwrap();
    let _token = service
        .liveliness()
        .declare_token(keys::instance_token("fake-a").unwrap())
        .wait()
        .unwrap();
    // The fake service's state of each robot, answered on the robot's state key.
    let states: Arc<Mutex<HashMap<String, SessionState>>> = Arc::default();
    let answer = Arc::clone(&states);
    let _state = service
        .declare_queryable(keys::state(fleet, "*").unwrap())
        .callback(move |query| {
            let robot = query.key_expr().as_str().rsplit('/').nth(1).unwrap_or("");
            let state = answer.lock().unwrap().get(robot).cloned();
            if let Some(state) = state {
                query
                    .reply(query.key_expr().clone(), encode(&state))
                    .wait()
                    .unwrap();
            }
        })
        .wait()
        .unwrap();
    let mut ends: Vec<String> = Vec::new();
    let mut ends_of = |session: &str| {
        while let Ok(Some(sample)) = frames.try_recv() {
            if let Ok(Inbound::SessionEnd(end)) =
                decode_inbound(&sample.payload().to_bytes(), &Default::default())
            {
                ends.push(end.session);
            }
        }
        ends.iter().filter(|s| *s == session).count()
    };
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();

    // Frames still to apply: close waits until the service's state shows the session closed.
    let robot = conn.robot(fleet, "r3").unwrap();
    for features in [[1], [2], [3]] {
        robot.publish(&features).unwrap();
    }
    let session = robot.session_id();
    let state = session_state("r3", &session, true, 1);
    states.lock().unwrap().insert("r3".into(), state);
    let closer = {
        let (states, session) = (Arc::clone(&states), session.clone());
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(400));
            let state = session_state("r3", &session, false, 2);
            states.lock().unwrap().insert("r3".into(), state);
        })
    };
    let started = Instant::now();
    robot.close().unwrap();
    let (min, max) = (Duration::from_millis(400), Duration::from_secs(3));
    assert_took("a close confirmed late", started.elapsed(), min, max);
    closer.join().unwrap();
    wait_until("the end of r3", || ends_of(&session) == 1);

    // Every frame applied, the end missing: the end is put again after the grace, once.
    let robot = conn.robot(fleet, "r4").unwrap();
    robot.publish(&[1]).unwrap();
    robot.publish(&[2]).unwrap();
    let session = robot.session_id();
    let state = session_state("r4", &session, true, 1);
    states.lock().unwrap().insert("r4".into(), state);
    let started = Instant::now();
    robot.close().unwrap();
    let (min, max) = (Duration::from_millis(300), Duration::from_secs(3));
    assert_took("a close with the end missing", started.elapsed(), min, max);
    wait_until("the end of r4 twice", || ends_of(&session) == 2);

    // Never confirmed (no state of the robot: a take-over that does not finish): released
    // after the timeout, without an error.
    let options = RobotOptions {
        close_timeout: Duration::from_millis(600),
        ..RobotOptions::default()
    };
    let robot = conn.robot_with(fleet, "r5", options).unwrap();
    robot.publish(&[1]).unwrap();
    let session = robot.session_id();
    let started = Instant::now();
    robot.close().unwrap();
    let (min, max) = (Duration::from_millis(600), Duration::from_secs(2));
    assert_took("an unconfirmed close", started.elapsed(), min, max);
    assert_eq!(ends_of(&session), 1);

    // A zero timeout is the old close: the end, then the release.
    let robot = conn.robot(fleet, "r6").unwrap();
    robot.publish(&[1]).unwrap();
    let started = Instant::now();
    robot.close_within(Duration::ZERO).unwrap();
    assert_took(
        "a close without waiting",
        started.elapsed(),
        Duration::ZERO,
        Duration::from_secs(2),
    );
    conn.close().unwrap();
    service.close().wait().unwrap();
}

#[test]
fn robot_close_does_not_wait_without_a_live_instance() {
    let (service, endpoint) = router();
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let robot = conn.robot("fleet", "r7").unwrap();
    robot.publish(&[1]).unwrap();
    let started = Instant::now();
    robot.close().unwrap(); // the default 5 s timeout
    let within = Duration::from_millis(1500);
    assert_took(
        "a close with no service",
        started.elapsed(),
        Duration::ZERO,
        within,
    );
    // Dropping the publisher closes it the same way.
    let robot = conn.robot("fleet", "r8").unwrap();
    robot.publish(&[1]).unwrap();
    let started = Instant::now();
    drop(robot);
    assert_took(
        "a drop with no service",
        started.elapsed(),
        Duration::ZERO,
        within,
    );
    conn.close().unwrap();
    service.close().wait().unwrap();
}

/// The `AreaGraph` a fake service instance answers for `robot`: two areas and a passage.
fn area_graph(robot: &str, instance: &str, epoch: u64, frames: u64) -> AreaGraph {
    let area = |id: u64, frames: u64, first_seq: u64| AreaNode {
        id,
        frames,
        visits: 1,
        first_seq,
        last_seq: first_seq + frames - 1,
        features: vec![id],
    };
    AreaGraph {
        fleet: "fleet".into(),
        robot: robot.into(),
        session: "s9".into(),
        instance: instance.into(),
        epoch,
        method: Method::Areas,
        areas: vec![area(0, frames, 0), area(1, 1, frames)],
        passages: vec![Passage {
            a: 0,
            b: 1,
            a_to_b: 1,
            b_to_a: 0,
            boundary_features: vec![(0, 1)],
        }],
    }
}

#[test]
fn area_graph_queries_keep_one_graph_per_robot() {
    let (service, endpoint) = router();
    // A hand-over for r9 (the old owner has more frames, the new one a higher epoch), and r10.
    let answers = [
        area_graph("r9", "i7", 7, 10),
        area_graph("r9", "i3", 3, 90),
        area_graph("r10", "i2", 2, 5),
    ];
    let mut queryables = Vec::new();
    for graph in &answers {
        let key = keys::areas(&graph.fleet, &graph.robot).unwrap();
        let reply = encode(graph);
        let reply_key = key.clone();
        queryables.push(
            service
                .declare_queryable(key)
                .callback(move |query| {
                    query
                        .reply(reply_key.as_str(), reply.clone())
                        .wait()
                        .unwrap();
                })
                .wait()
                .unwrap(),
        );
    }
    wait_until("every queryable to answer", || {
        let replies = service
            .get(keys::areas("fleet", "*").unwrap())
            .target(zenoh::query::QueryTarget::All)
            .consolidation(zenoh::query::ConsolidationMode::None)
            .timeout(Duration::from_secs(2))
            .wait()
            .unwrap();
        replies
            .iter()
            .filter(|reply| reply.result().is_ok())
            .count()
            == answers.len()
    });
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let ask = Duration::from_secs(2);
    let current = conn.area_graph("fleet", "r9", ask).unwrap();
    assert_eq!(current.as_ref(), Some(&answers[0]));
    let all: Vec<(String, String)> = conn
        .area_graphs("fleet", "*", ask)
        .unwrap()
        .into_iter()
        .map(|graph| (graph.robot, graph.instance))
        .collect();
    assert_eq!(
        all,
        [
            ("r10".to_owned(), "i2".to_owned()),
            ("r9".to_owned(), "i7".to_owned())
        ]
    );
    assert_eq!(conn.area_graph("fleet", "r11", ask).unwrap(), None);

    // A robot sees the graph of its own session only.
    let own = RobotOptions {
        session_id: Some("s9".into()),
        ..RobotOptions::default()
    };
    let robot = conn.robot_with("fleet", "r9", own).unwrap();
    assert_eq!(robot.area_graph(ask).unwrap().as_ref(), Some(&answers[0]));
    robot.close_within(Duration::ZERO).unwrap();
    let robot = conn.robot("fleet", "r10").unwrap();
    assert_eq!(robot.area_graph(ask).unwrap(), None);
    robot.close_within(Duration::ZERO).unwrap();
    drop(queryables);
    conn.close().unwrap();
    service.close().wait().unwrap();
}

/// A publisher on `robot`'s errors key of `fleet`, once the robot's subscriber matches it.
fn errors_publisher(
    service: &Session,
    fleet: &str,
    robot: &str,
) -> zenoh::pubsub::Publisher<'static> {
    let publisher = service
        .declare_publisher(keys::errors(fleet, robot).unwrap())
        .wait()
        .unwrap();
    wait_until("the robot's errors subscriber", || {
        publisher.matching_status().wait().unwrap().matching()
    });
    publisher
}

#[test]
fn flush_errors_waits_until_every_report_received_is_handled() {
    let (service, endpoint) = router();
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    // on_error tells when it starts, then blocks until the test lets it go (at most WAIT, so
    // a failing test still closes the robot).
    let (entered_tx, entered_rx) = std::sync::mpsc::channel::<()>();
    let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
    let options = RobotOptions {
        on_error: Some(Box::new(move |_: &Error| {
            entered_tx.send(()).unwrap();
            let _ = release_rx.recv_timeout(WAIT);
        })),
        ..RobotOptions::default()
    };
    let robot = conn.robot_with("fleet", "r1", options).unwrap();
    assert!(robot.flush_errors(Duration::ZERO)); // nothing received: nothing to wait for
    let errors = errors_publisher(&service, "fleet", "r1");
    errors
        .put(encode(&report(&robot.session_id(), ErrorCode::SeqGap, 1)))
        .wait()
        .unwrap();
    entered_rx.recv_timeout(WAIT).expect("on_error called");
    // Received, not handled yet: on_error has not returned.
    assert!(!robot.flush_errors(Duration::from_millis(100)));
    release_tx.send(()).unwrap();
    assert!(robot.flush_errors(WAIT));
    assert_eq!(robot.status().count(ErrorCode::SeqGap), 1);
    robot.close_within(Duration::ZERO).unwrap();
    drop(errors);
    conn.close().unwrap();
    service.close().wait().unwrap();
}

#[test]
fn auto_new_session_never_takes_the_robot_over_from_another_publisher() {
    let (service, endpoint) = router();
    // The service holds another publisher's session of this robot name open.
    let other = encode(&session_state("r1", "the-other-publisher", true, 0));
    let _state = service
        .declare_queryable(keys::state("fleet", "r1").unwrap())
        .callback(move |query| {
            query
                .reply(query.key_expr().clone(), other.clone())
                .wait()
                .unwrap();
        })
        .wait()
        .unwrap();
    let conn = Connection::connect(&[&endpoint], WAIT).unwrap();
    let robot = conn.robot("fleet", "r1").unwrap();
    robot.publish(&[1]).unwrap();
    let errors = errors_publisher(&service, "fleet", "r1");
    let first = robot.session_id();
    errors
        .put(encode(&report(&first, ErrorCode::SessionClosed, 1)))
        .wait()
        .unwrap();
    wait_until("the robot to see SESSION_CLOSED", || {
        robot.status().closed_by_service
    });
    match robot.publish(&[2]) {
        Err(ClientError::SessionClosed(msg)) => {
            assert!(msg.contains("the-other-publisher"), "{msg}");
        }
        other => panic!("expected SessionClosed, got {other:?}"),
    }
    assert_eq!((robot.session_id(), robot.status().sessions), (first, 1));
    // The caller decides: a new session of its own, numbered from 0.
    robot.new_session(None).unwrap();
    assert_eq!(robot.publish(&[3]).unwrap(), 0);
    robot.close_within(Duration::ZERO).unwrap();
    drop(errors);
    conn.close().unwrap();
    service.close().wait().unwrap();
}

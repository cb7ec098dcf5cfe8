//! A fleet of robots publishes a few frames each, then ends every session together with
//! `close_all`: `cargo run --example close_fleet -- [-e ENDPOINT] [--fleet NAME] [--robots N]
//! [--frames M] [--timeout-ms T] [--serve-wait-ms W]`.
//!
//! It waits up to `--serve-wait-ms` (10 s) for a lessmap instance to serve each robot, and
//! publishes either way (an unserved robot's frames wait in its cache). Prints one JSON line:
//! the robots and their sessions, the time `close_all` took, and the ends it left
//! unconfirmed (with the reason) or failed to send.

use std::time::{Duration, Instant};

use lessmap_client::{close_all, ClientError, Connection, RobotPublisher, DEFAULT_ENDPOINT};
use serde_json::json;

fn number(value: Option<String>, what: &str) -> u64 {
    value.and_then(|v| v.parse().ok()).unwrap_or_else(|| {
        eprintln!("close_fleet: {what} needs a number");
        std::process::exit(2);
    })
}

fn main() -> Result<(), ClientError> {
    let mut endpoint = DEFAULT_ENDPOINT.to_owned();
    let mut fleet = "example".to_owned();
    let (mut robots, mut frames, mut timeout_ms, mut serve_wait_ms) = (8, 5, 5000, 10_000);
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "-e" | "--endpoint" => endpoint = it.next().unwrap_or_default(),
            "--fleet" => fleet = it.next().unwrap_or_default(),
            "--robots" => robots = number(it.next(), "--robots"),
            "--frames" => frames = number(it.next(), "--frames"),
            "--timeout-ms" => timeout_ms = number(it.next(), "--timeout-ms"),
            "--serve-wait-ms" => serve_wait_ms = number(it.next(), "--serve-wait-ms"),
            other => {
                eprintln!("close_fleet: unknown argument {other:?}");
                std::process::exit(2);
            }
        }
    }
    let conn = Connection::connect(&[&endpoint], Duration::from_secs(10))?;
    let serve_wait = Duration::from_millis(serve_wait_ms);
    let mut fleet_robots: Vec<RobotPublisher> = Vec::new();
    for i in 0..robots {
        let robot = conn.robot(&fleet, &format!("robot-{i}"))?;
        if !serve_wait.is_zero() && !robot.wait_for_service(serve_wait)? {
            eprintln!("close_fleet: nobody serves {fleet}/{}", robot.robot());
        }
        fleet_robots.push(robot);
    }
    for robot in &fleet_robots {
        for seq in 0..frames {
            // One room of 40 landmarks, seen a few at a time.
            let seen: Vec<u64> = (0..6).map(|k| (seq + k) % 40).collect();
            robot.publish(&seen)?;
        }
    }
    let sessions: serde_json::Map<String, serde_json::Value> = fleet_robots
        .iter()
        .map(|robot| (robot.robot().to_owned(), json!(robot.session_id())))
        .collect();
    let started = Instant::now();
    let report = close_all(fleet_robots, Duration::from_millis(timeout_ms));
    let close_s = started.elapsed().as_secs_f64();
    let unconfirmed: Vec<serde_json::Value> = report
        .unconfirmed
        .iter()
        .map(|end| {
            json!({
                "robot": end.robot,
                "session": end.session,
                "last_seq": end.last_seq,
                "reason": end.reason.to_string(),
            })
        })
        .collect();
    let failures: Vec<serde_json::Value> = report
        .failures
        .iter()
        .map(|failure| json!({"robot": failure.robot, "error": failure.error.to_string()}))
        .collect();
    println!(
        "{}",
        json!({
            "fleet": fleet,
            "robots": robots,
            "frames": robots * frames,
            "sessions": sessions,
            "closed": report.closed,
            "close_s": close_s,
            "timeout_s": timeout_ms as f64 / 1000.0,
            "unconfirmed": unconfirmed,
            "failures": failures,
        })
    );
    conn.close()
}

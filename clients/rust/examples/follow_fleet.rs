//! Print every transition of the `example` fleet for 20 seconds, then each robot's state.
//!
//! `cargo run --example follow_fleet [-- -e ENDPOINT] [--fleet NAME] [--seconds S] [--json]
//! [--until-closed]`
//!
//! * `--json`: one JSON line per transition, then one per state (the messages as JSON).
//! * `--until-closed`: stop as soon as every robot of the fleet has ended its session and all
//!   of its transitions arrived (the service's `SessionState.transitions`), or at the deadline.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use lessmap_client::{ClientError, Connection, DEFAULT_ENDPOINT, DEFAULT_HISTORY};

struct Args {
    endpoint: String,
    fleet: String,
    seconds: f64,
    json: bool,
    until_closed: bool,
}

fn parse_args() -> Args {
    let mut args = Args {
        endpoint: DEFAULT_ENDPOINT.to_owned(),
        fleet: "example".to_owned(),
        seconds: 20.0,
        json: false,
        until_closed: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "-e" | "--endpoint" => args.endpoint = it.next().unwrap_or_default(),
            "--fleet" => args.fleet = it.next().unwrap_or_default(),
            "--seconds" => args.seconds = it.next().and_then(|s| s.parse().ok()).unwrap_or(20.0),
            "--json" => args.json = true,
            "--until-closed" => args.until_closed = true,
            other => {
                eprintln!("follow_fleet: unknown argument {other:?}");
                std::process::exit(2);
            }
        }
    }
    args
}

/// `0.307` for a value, `-` for none (ncut and lambda2 are set for spectral splits only).
fn three_decimals(value: Option<f64>) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.3}"))
}

fn main() -> Result<(), ClientError> {
    let args = parse_args();
    let conn = Connection::connect(&[&args.endpoint], Duration::from_secs(10))?;
    // History: transitions published before we joined come first, then live ones.
    let mut sub = conn.subscribe_transitions(&args.fleet, "*", Some(DEFAULT_HISTORY))?;
    eprintln!("following the transitions of fleet {}", args.fleet);
    let deadline = Instant::now() + Duration::from_secs_f64(args.seconds);
    let mut received: HashMap<(String, String), u64> = HashMap::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            break;
        }
        let quiet = if args.until_closed {
            left.min(Duration::from_secs(1))
        } else {
            left
        };
        match sub.recv(quiet) {
            Some(t) => {
                *received
                    .entry((t.robot.clone(), t.session.clone()))
                    .or_insert(0) += 1;
                if args.json {
                    println!("{}", serde_json::to_string(&t).expect("json"));
                } else {
                    println!(
                        "{}: frame {} {} ncut={} lambda2={} closed submap {} ({} features), \
                         area {} -> {}{}",
                        t.robot,
                        t.seq,
                        t.reason.as_str(),
                        three_decimals(t.ncut),
                        three_decimals(t.lambda2),
                        t.closed.id,
                        t.closed.features.len(),
                        t.left_area,
                        t.area,
                        if t.revisit { " (revisit)" } else { "" }
                    );
                }
            }
            None if args.until_closed => {
                // Quiet for a second: done if every robot's session is closed and complete.
                let states = conn.states(&args.fleet, "*", Duration::from_secs(2))?;
                let complete = !states.is_empty()
                    && states.iter().all(|s| {
                        let key = (s.robot.clone(), s.session.clone());
                        !s.open && received.get(&key).copied().unwrap_or(0) == s.transitions
                    });
                if complete {
                    break;
                }
            }
            None => break,
        }
    }
    sub.close()?;
    for state in conn.states(&args.fleet, "*", Duration::from_secs(2))? {
        if args.json {
            println!("{}", serde_json::to_string(&state).expect("json"));
        } else {
            println!(
                "{} {} frames, {} transitions",
                state.robot, state.frames_applied, state.transitions
            );
        }
    }
    if sub.duplicates() + sub.dropped_stale() + sub.dropped() + sub.undecodable() > 0 {
        eprintln!(
            "skipped: {} repeats, {} stale, {} dropped, {} undecodable",
            sub.duplicates(),
            sub.dropped_stale(),
            sub.dropped(),
            sub.undecodable()
        );
    }
    drop(sub);
    conn.close()
}

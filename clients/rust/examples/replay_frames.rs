//! Publish a recorded frames file (`<name>.frames.jsonl`) as its robots would have, then end
//! their sessions: `cargo run --example replay_frames -- FILE [-e ENDPOINT] [--fleet NAME]`.
//!
//! Each line is `{"robot", "seq", "stamp", "features", "pose"?}`; every robot of the file
//! publishes under its own session, with the file's seqs and stamps, as fast as Zenoh takes
//! them (congestion control *block*), then ends every session together (`close_all`). Prints
//! one JSON summary line.

use std::collections::BTreeMap;
use std::io::BufRead;
use std::time::{Duration, Instant};

use lessmap_client::{
    close_all, ClientError, Connection, RobotPublisher, DEFAULT_CLOSE_TIMEOUT, DEFAULT_ENDPOINT,
};
use serde_json::Value;

struct Row {
    robot: String,
    seq: u64,
    stamp_s: f64,
    features: Vec<u64>,
    pose: Option<[f64; 3]>,
}

fn parse(line: &str, at: &str) -> Row {
    let fail = |what: &str| -> ! {
        eprintln!("replay_frames: {at}: {what}");
        std::process::exit(1);
    };
    let value: Value = serde_json::from_str(line).unwrap_or_else(|err| fail(&err.to_string()));
    let robot = value["robot"]
        .as_str()
        .unwrap_or_else(|| fail("no robot"))
        .to_owned();
    let seq = value["seq"].as_u64().unwrap_or_else(|| fail("no seq"));
    let stamp_s = value["stamp"].as_f64().unwrap_or_else(|| fail("no stamp"));
    let features = value["features"]
        .as_array()
        .unwrap_or_else(|| fail("no features"))
        .iter()
        .map(|f| f.as_u64().unwrap_or_else(|| fail("a feature is not an id")))
        .collect();
    let pose = match &value["pose"] {
        Value::Null => None,
        Value::Array(xs) if xs.len() == 3 => {
            let x = |i: usize| xs[i].as_f64().unwrap_or_else(|| fail("a pose value"));
            Some([x(0), x(1), x(2)])
        }
        _ => fail("pose is not 3 numbers"),
    };
    Row {
        robot,
        seq,
        stamp_s,
        features,
        pose,
    }
}

fn main() -> Result<(), ClientError> {
    let mut path = None;
    let mut endpoint = DEFAULT_ENDPOINT.to_owned();
    let mut fleet = "example".to_owned();
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "-e" | "--endpoint" => endpoint = it.next().unwrap_or_default(),
            "--fleet" => fleet = it.next().unwrap_or_default(),
            _ if path.is_none() => path = Some(arg),
            other => {
                eprintln!("replay_frames: unknown argument {other:?}");
                std::process::exit(2);
            }
        }
    }
    let Some(path) = path else {
        eprintln!("usage: replay_frames FILE [-e ENDPOINT] [--fleet NAME]");
        std::process::exit(2);
    };
    let file = std::fs::File::open(&path).unwrap_or_else(|err| {
        eprintln!("replay_frames: {path}: {err}");
        std::process::exit(1);
    });
    let mut rows = Vec::new();
    for (number, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.unwrap_or_else(|err| {
            eprintln!("replay_frames: {path}:{}: {err}", number + 1);
            std::process::exit(1);
        });
        if !line.trim().is_empty() {
            rows.push(parse(&line, &format!("{path}:{}", number + 1)));
        }
    }
    let conn = Connection::connect(&[&endpoint], Duration::from_secs(10))?;
    let mut robots: BTreeMap<String, RobotPublisher> = BTreeMap::new();
    for row in &rows {
        if !robots.contains_key(&row.robot) {
            let robot = conn.robot(&fleet, &row.robot)?;
            // Served, and the owner's frames subscription matches: no frame is published
            // into the void.
            if !robot.wait_for_service(Duration::from_secs(30))? {
                eprintln!(
                    "replay_frames: no lessmap instance serves {fleet}/{}",
                    row.robot
                );
                std::process::exit(1);
            }
            robots.insert(row.robot.clone(), robot);
        }
    }
    let started = Instant::now();
    for row in &rows {
        robots[&row.robot].publish_frame(
            &row.features,
            Some(row.stamp_s),
            row.pose,
            Some(row.seq),
        )?;
    }
    let count = robots.len();
    // Every SessionEnd (with the last seq) first, then one wait for the service to confirm
    // them all.
    let report = close_all(robots.into_values(), DEFAULT_CLOSE_TIMEOUT);
    if let Some(failure) = report.failures.into_iter().next() {
        return Err(failure.error);
    }
    println!(
        "{{\"frames\": {}, \"robots\": {count}, \"elapsed_s\": {:.3}}}",
        rows.len(),
        started.elapsed().as_secs_f64()
    );
    conn.close()
}

//! A robot walks from one room into another; lessmap should report one transition.
//!
//! Run `lessmap serve` first, then `cargo run --example follow_fleet` in another terminal,
//! then `cargo run --example publish_walk [-- -e tcp/127.0.0.1:7447]`.

use std::time::Duration;

use lessmap_client::{ClientError, Connection, DEFAULT_ENDPOINT};

/// A small deterministic generator (xorshift64*): the walk is the same at every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// `k` distinct values of `range`, as Python's `random.sample` gives them.
    fn sample(&mut self, range: std::ops::Range<u64>, k: usize) -> Vec<u64> {
        let mut pool: Vec<u64> = range.collect();
        for i in 0..k {
            let j = i + (self.next() % (pool.len() - i) as u64) as usize;
            pool.swap(i, j);
        }
        pool.truncate(k);
        pool
    }
}

const ROOM_A: std::ops::Range<u64> = 0..20; // landmark IDs on the walls of room A
const ROOM_B: std::ops::Range<u64> = 100..120; // and of room B

fn main() -> Result<(), ClientError> {
    let args: Vec<String> = std::env::args().collect();
    let endpoint = match args.iter().position(|a| a == "-e" || a == "--endpoint") {
        Some(i) => args.get(i + 1).cloned().unwrap_or_default(),
        None => DEFAULT_ENDPOINT.to_owned(),
    };
    let mut rng = Rng(1);
    // Client mode, no multicast scouting: the router of `lessmap serve`.
    let conn = Connection::connect(&[&endpoint], Duration::from_secs(10))?;
    if !conn.wait_for_service(Duration::from_secs(10))? {
        eprintln!("no lessmap service is running (start `lessmap serve`)");
        std::process::exit(1);
    }
    let robot = conn.robot("example", "walker")?;
    robot.wait_for_service(Duration::from_secs(10))?;
    for step in 0..84 {
        let seen = if step < 40 {
            rng.sample(ROOM_A, 12)
        } else if step < 44 {
            // In the door: a bit of both rooms.
            let mut both = rng.sample(ROOM_A, 4);
            both.extend(rng.sample(ROOM_B, 4));
            both
        } else {
            rng.sample(ROOM_B, 12)
        };
        let seq = robot.publish(&seen)?;
        println!("frame {seq}: {} features", seen.len());
        std::thread::sleep(Duration::from_millis(50));
    }
    robot.close()?; // the SessionEnd with the last seq
    conn.close()
}

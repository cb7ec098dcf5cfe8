//! A Rust client of lessmap, the online environment-segmentation service, on Eclipse Zenoh.
//!
//! It speaks the wire contract v4 (`schemas/README.md` of the lessmap repository): the typed
//! messages and their msgpack codec ([`messages`], [`codec`]), names, keys and partitions
//! ([`names`]), a robot publisher ([`RobotPublisher`]; [`close_all`] ends many with one shared
//! wait, [`closing`]) and fleet subscriptions ([`subscription`]) and queries ([`query`]), all
//! declared from one [`Connection`], as in the Python SDK, and the fleet merge of the robots'
//! area graphs ([`fleet_areas`]).
//!
//! Modules and what each uses of the crate (no cycles, checked by `tests/module_graph.rs`; a
//! module uses only those above it):
//!
//! * [`error`]: nothing (every error type: [`ErrorCode`], [`WireError`], [`FleetMergeError`],
//!   [`ClientError`]); `wire_serde` (serde glue of the wire maps): nothing;
//! * [`names`]: error; `checks` (the messages' range checks): error, names;
//! * [`messages`]: checks, error, names, wire_serde; [`codec`]: error, messages, names,
//!   wire_serde;
//! * [`fleet_areas`]: error, messages;
//! * [`query`]: error, codec, fleet_areas, messages, names;
//! * [`subscription`]: error, codec, messages;
//! * [`closing`]: error, messages, names, query;
//! * `follower` (what a robot follows besides its frames): error, codec, messages, names, query;
//! * [`robot`]: error, closing, codec, follower, messages, names, query;
//! * [`connection`]: error, fleet_areas, messages, names, query, robot, subscription.
//!
//! Types that moved keep their old paths too (`connection::ClientError`,
//! `codec::WireError`, `robot::EndProgress`, ...).
//!
//! ```no_run
//! use std::time::Duration;
//! use lessmap_client::Connection;
//!
//! let conn = Connection::connect(&["tcp/127.0.0.1:7447"], Duration::from_secs(10))?;
//! let robot = conn.robot("warehouse", "amr-7")?;
//! robot.publish(&[12, 40, 41, 97])?; // seq 0, stamped now
//! robot.close()?; // SessionEnd with the last seq; the cache stays until the service confirms it
//! # Ok::<(), lessmap_client::ClientError>(())
//! ```

mod checks;

/// The README's program, compiled by `cargo test` so that it stays true.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;

pub mod closing;
pub mod codec;
pub mod connection;
pub mod error;
pub mod fleet_areas;
mod follower;
pub mod messages;
pub mod names;
pub mod query;
pub mod robot;
pub mod subscription;
mod wire_serde;

pub use closing::{
    end_progress, CloseFailure, CloseReport, EndProgress, UnconfirmedEnd, UnconfirmedReason,
};
pub use codec::{decode, decode_inbound, encode, encoding, Inbound, WireLimits};
pub use connection::{Connection, DEFAULT_ENDPOINT, DEFAULT_HISTORY};
pub use error::{ClientError, ErrorCode, FleetMergeError, WireError};
pub use fleet_areas::{fleet_graph, FleetEdge, FleetGraph, FleetNode, FleetParams};
pub use messages::{
    AreaGraph, AreaNode, Error, Frame, Health, Message, Method, Passage, Reason, SessionEnd,
    SessionState, Submap, SubmapSummary, Transition,
};
pub use names::{keys, owner_and_standby, partition_of, ranking, validate_name};
pub use robot::{
    close_all, new_session_id, RobotOptions, RobotPublisher, RobotStatus, DEFAULT_CLOSE_TIMEOUT,
};
pub use subscription::Subscription;

//! A Rust client of lessmap, the online environment-segmentation service, on Eclipse Zenoh.
//!
//! It speaks the wire contract v2 (`schemas/README.md` of the lessmap repository): the typed
//! messages and their msgpack codec ([`messages`], [`codec`]), names, keys and partitions
//! ([`names`]).

pub mod codec;
pub mod messages;
pub mod names;

pub use codec::{
    decode, decode_inbound, encode, encoding, ErrorCode, Inbound, WireError, WireLimits,
};
pub use messages::{
    Error, Frame, Health, Message, Reason, SessionEnd, SessionState, Submap, SubmapSummary,
    Transition,
};
pub use names::{keys, owner_and_standby, partition_of, ranking, validate_name};

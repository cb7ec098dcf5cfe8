//! Encode messages to msgpack and decode untrusted bytes into validated messages.
//!
//! The order of checks is the contract's (section 7), so every reader reports the same code
//! for the same bytes:
//!
//! 1. payload size, before a byte is unpacked (`max_payload_bytes`);
//! 2. msgpack, every length bounded while reading (arrays, strings, maps, nesting), no `bin`
//!    or extension values, string map keys, nothing after the value;
//! 3. envelope: a map, a `type` accepted here, `v == 4` (`WIRE_VERSION`);
//! 4. `Frame.features` length;
//! 5. the fields, by serde (types, unknown and missing fields), then ranges and names.
//!
//! Every failure is a [`WireError`] carrying an [`ErrorCode`]; nothing else escapes.

use rmpv::{Utf8String, Value};

pub use crate::error::{ErrorCode, WireError};
use crate::messages::{Frame, Message, SessionEnd};
use crate::names::WIRE_VERSION;
use crate::wire_serde::{from_value, kind_of};

/// Zenoh encoding of every lessmap payload; the schema suffix names the message.
pub const MEDIA_TYPE: &str = "application/msgpack";
/// Most entries in any lessmap map.
const MAX_MAP_LEN: usize = 32;
/// Most nested arrays and maps, as the reference reader's msgpack allows.
const MAX_DEPTH: usize = 1024;

/// Bounds a reader enforces (contract section 8); the defaults are the contract's.
///
/// Format bounds (name length, seq, feature id, detail length) are fixed in the contract and
/// checked in [`crate::messages`]; these are the receiver-policy limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WireLimits {
    /// Largest encoded message, checked before unpacking anything.
    pub max_payload_bytes: usize,
    /// Longest `Frame.features`; bounds every array in a robot's payload.
    pub max_features_per_frame: usize,
    /// Longest array in a service payload.
    pub max_list_len: usize,
}

impl Default for WireLimits {
    fn default() -> Self {
        WireLimits {
            max_payload_bytes: 1_048_576,
            max_features_per_frame: 4096,
            max_list_len: 100_000,
        }
    }
}

/// Longest string anywhere, in UTF-8 bytes (`max_detail_len`).
pub const MAX_DETAIL_LEN: usize = 1024;

/// The Zenoh encoding string of a message type, e.g. `application/msgpack;lessmap.Frame/4`.
pub fn encoding<M: Message>() -> String {
    format!("{MEDIA_TYPE};lessmap.{}/{WIRE_VERSION}", M::TYPE)
}

/// Encode a message canonically: a msgpack map in field order, integers in their smallest
/// encoding, floats as float64.
pub fn encode<M: Message>(message: &M) -> Vec<u8> {
    // Writing to a Vec fails only if a Serialize impl does, and ours never do.
    rmp_serde::to_vec_named(message).expect("lessmap messages always serialize")
}

/// Decode one untrusted payload expecting exactly the message type `M`, with default limits.
pub fn decode<M: Message>(data: &[u8]) -> Result<M, WireError> {
    decode_with::<M>(data, &WireLimits::default())
}

/// Decode one untrusted payload expecting exactly the message type `M`.
pub fn decode_with<M: Message>(data: &[u8], limits: &WireLimits) -> Result<M, WireError> {
    let inbound = M::TYPE == Frame::TYPE || M::TYPE == SessionEnd::TYPE;
    let map = envelope(data, limits, inbound, &[M::TYPE])?.1;
    fields::<M>(map)
}

/// What a robot puts on its `frames` key.
#[derive(Clone, Debug, PartialEq)]
pub enum Inbound {
    /// One sensor frame.
    Frame(Frame),
    /// The end of a session.
    SessionEnd(SessionEnd),
}

/// Decode a payload from a robot's `frames` key: a `Frame` or a `SessionEnd`.
pub fn decode_inbound(data: &[u8], limits: &WireLimits) -> Result<Inbound, WireError> {
    let (kind, map) = envelope(data, limits, true, &[Frame::TYPE, SessionEnd::TYPE])?;
    if kind == Frame::TYPE {
        fields::<Frame>(map).map(Inbound::Frame)
    } else {
        fields::<SessionEnd>(map).map(Inbound::SessionEnd)
    }
}

/// The entries of a msgpack map.
type Entries = Vec<(Value, Value)>;

/// Check size, msgpack and envelope; return the type name and the other entries.
fn envelope(
    data: &[u8],
    limits: &WireLimits,
    inbound: bool,
    accepted: &[&'static str],
) -> Result<(&'static str, Entries), WireError> {
    if data.len() > limits.max_payload_bytes {
        return Err(WireError::with_limit(
            ErrorCode::LimitExceeded,
            "max_payload_bytes",
            format!(
                "payload of {} bytes exceeds max_payload_bytes={}",
                data.len(),
                limits.max_payload_bytes
            ),
        ));
    }
    // Robots' arrays are bounded by the per-frame limit, the service's by the list limit;
    // a pose needs 3 slots whatever the limits say.
    let (array_max, array_limit) = if inbound {
        (
            limits.max_features_per_frame.max(3),
            "max_features_per_frame",
        )
    } else {
        (
            limits
                .max_list_len
                .max(limits.max_features_per_frame)
                .max(3),
            "max_list_len",
        )
    };
    let mut reader = Reader {
        data,
        pos: 0,
        array_max,
        array_limit,
    };
    let value = reader.value()?;
    if reader.pos != data.len() {
        return Err(WireError::malformed(format!(
            "{} bytes after the msgpack value",
            data.len() - reader.pos
        )));
    }
    let Value::Map(entries) = value else {
        return Err(WireError::malformed(format!(
            "top level is a msgpack {}, not a map",
            kind_of(&value)
        )));
    };
    let kind = entries
        .iter()
        .find(|(key, _)| key.as_str() == Some("type"))
        .and_then(|(_, value)| value.as_str())
        .and_then(|name| accepted.iter().copied().find(|known| *known == name));
    let Some(kind) = kind else {
        return Err(WireError::new(
            ErrorCode::UnknownType,
            format!("type is not one of {}", accepted.join(", ")),
        ));
    };
    let version = entries
        .iter()
        .find(|(key, _)| key.as_str() == Some("v"))
        .map(|(_, value)| value);
    if !matches!(version, Some(Value::Integer(n)) if n.as_u64() == Some(WIRE_VERSION)) {
        return Err(WireError::new(
            ErrorCode::UnsupportedVersion,
            format!("{kind} has no v={WIRE_VERSION}; this reader speaks v={WIRE_VERSION}"),
        ));
    }
    if kind == Frame::TYPE {
        if let Some((_, Value::Array(features))) = entries
            .iter()
            .find(|(key, _)| key.as_str() == Some("features"))
        {
            if features.len() > limits.max_features_per_frame {
                return Err(WireError::with_limit(
                    ErrorCode::LimitExceeded,
                    "max_features_per_frame",
                    format!(
                        "Frame has {} features; max_features_per_frame={}",
                        features.len(),
                        limits.max_features_per_frame
                    ),
                ));
            }
        }
    }
    let mut rest = Vec::with_capacity(entries.len());
    for (key, value) in entries {
        if matches!(key.as_str(), Some("type" | "v")) {
            continue;
        }
        if has_binary(&key) || has_binary(&value) {
            return Err(WireError::invalid(
                "a msgpack bin or extension value: lessmap messages use neither",
            ));
        }
        rest.push((key, value));
    }
    Ok((kind, rest))
}

/// Deserialize the fields (type and v removed) and check ranges and names.
fn fields<M: Message>(map: Vec<(Value, Value)>) -> Result<M, WireError> {
    let message: M = from_value(Value::Map(map)).map_err(|err| {
        WireError::invalid(
            format!("{}: {err}", M::TYPE)
                .chars()
                .take(1024)
                .collect::<String>(),
        )
    })?;
    message.validate()?;
    Ok(message)
}

fn has_binary(value: &Value) -> bool {
    // Iterative: a value may nest MAX_DEPTH deep.
    let mut stack = vec![value];
    while let Some(value) = stack.pop() {
        match value {
            Value::Binary(_) | Value::Ext(..) => return true,
            Value::Array(items) => stack.extend(items),
            Value::Map(entries) => {
                for (key, value) in entries {
                    stack.push(key);
                    stack.push(value);
                }
            }
            _ => {}
        }
    }
    false
}

/// A bounded msgpack reader: every length is checked before anything is allocated for it.
struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
    array_max: usize,
    array_limit: &'static str,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], WireError> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|end| *end <= self.data.len())
            .ok_or_else(|| WireError::malformed("truncated msgpack value"))?;
        let bytes = &self.data[self.pos..end];
        self.pos = end;
        Ok(bytes)
    }

    fn uint(&mut self, n: usize) -> Result<u64, WireError> {
        Ok(self
            .take(n)?
            .iter()
            .fold(0u64, |acc, byte| (acc << 8) | u64::from(*byte)))
    }

    fn int(&mut self, n: usize) -> Result<i64, WireError> {
        let raw = self.uint(n)?;
        let shift = 64 - 8 * n as u32;
        // Sign-extend the n-byte two's complement value.
        Ok(((raw << shift) as i64) >> shift)
    }

    /// Read one value without recursion: nesting is bounded by `MAX_DEPTH`, not by the stack
    /// of whichever thread decodes.
    fn value(&mut self) -> Result<Value, WireError> {
        let mut open: Vec<Open> = Vec::new();
        loop {
            let mut done = match self.item()? {
                Item::Value(value) => value,
                Item::Array(n) => {
                    self.check_open(&open, n, false)?;
                    if n > 0 {
                        // Every item takes at least one byte: never reserve more than is left.
                        let items = Vec::with_capacity(n.min(self.data.len() - self.pos));
                        open.push(Open::Array(items, n));
                        continue;
                    }
                    Value::Array(Vec::new())
                }
                Item::Map(n) => {
                    self.check_open(&open, n, true)?;
                    if n > 0 {
                        open.push(Open::Map(Vec::with_capacity(n), n, None));
                        continue;
                    }
                    Value::Map(Vec::new())
                }
            };
            // Hand the finished value to the containers it completes, innermost first.
            loop {
                let Some(top) = open.last_mut() else {
                    return Ok(done);
                };
                match top {
                    Open::Array(items, n) => {
                        items.push(done);
                        if items.len() < *n {
                            break;
                        }
                    }
                    Open::Map(entries, n, key) => {
                        match key.take() {
                            None => {
                                check_key(&done)?;
                                *key = Some(done);
                                break;
                            }
                            Some(k) => {
                                // Two readers could keep different values of a repeated
                                // key: the contract refuses the payload (section 4, rule 1).
                                if entries.iter().any(|(seen, _)| *seen == k) {
                                    return Err(WireError::new(
                                        ErrorCode::Invalid,
                                        format!("a map names the key {k} twice"),
                                    ));
                                }
                                entries.push((k, done));
                            }
                        }
                        if entries.len() < *n {
                            break;
                        }
                    }
                }
                done = match open.pop() {
                    Some(Open::Array(items, _)) => Value::Array(items),
                    Some(Open::Map(entries, _, _)) => Value::Map(entries),
                    None => unreachable!("a container was on the stack"),
                };
            }
        }
    }

    fn check_open(&self, open: &[Open], n: usize, map: bool) -> Result<(), WireError> {
        if open.len() >= MAX_DEPTH {
            return Err(WireError::malformed(format!(
                "msgpack nested deeper than {MAX_DEPTH}"
            )));
        }
        if map && n > MAX_MAP_LEN {
            return Err(WireError::invalid(format!(
                "a map of {n} entries: no lessmap map has more than {MAX_MAP_LEN} fields"
            )));
        }
        if !map && n > self.array_max {
            return Err(WireError::with_limit(
                ErrorCode::LimitExceeded,
                self.array_limit,
                format!(
                    "an array of {n} items exceeds {}={}",
                    self.array_limit, self.array_max
                ),
            ));
        }
        Ok(())
    }

    /// Read a scalar, or the header of an array or a map.
    fn item(&mut self) -> Result<Item, WireError> {
        let marker = self.take(1)?[0];
        let value = match marker {
            0x00..=0x7f => Value::from(marker),
            0x80..=0x8f => return Ok(Item::Map(usize::from(marker & 0x0f))),
            0x90..=0x9f => return Ok(Item::Array(usize::from(marker & 0x0f))),
            0xa0..=0xbf => self.string(usize::from(marker & 0x1f))?,
            0xc0 => Value::Nil,
            0xc1 => return Err(WireError::malformed("reserved msgpack byte 0xc1")),
            0xc2 => Value::Boolean(false),
            0xc3 => Value::Boolean(true),
            0xc4 => self.binary(1)?,
            0xc5 => self.binary(2)?,
            0xc6 => self.binary(4)?,
            0xc7 => self.ext(1)?,
            0xc8 => self.ext(2)?,
            0xc9 => self.ext(4)?,
            0xca => Value::F32(f32::from_bits(self.uint(4)? as u32)),
            0xcb => Value::F64(f64::from_bits(self.uint(8)?)),
            0xcc => Value::from(self.uint(1)?),
            0xcd => Value::from(self.uint(2)?),
            0xce => Value::from(self.uint(4)?),
            0xcf => Value::from(self.uint(8)?),
            0xd0 => Value::from(self.int(1)?),
            0xd1 => Value::from(self.int(2)?),
            0xd2 => Value::from(self.int(4)?),
            0xd3 => Value::from(self.int(8)?),
            0xd4 => self.ext_data(1)?,
            0xd5 => self.ext_data(2)?,
            0xd6 => self.ext_data(4)?,
            0xd7 => self.ext_data(8)?,
            0xd8 => self.ext_data(16)?,
            0xd9 => {
                let n = self.uint(1)? as usize;
                self.string(n)?
            }
            0xda => {
                let n = self.uint(2)? as usize;
                self.string(n)?
            }
            0xdb => {
                let n = self.uint(4)? as usize;
                self.string(n)?
            }
            0xdc => return Ok(Item::Array(self.uint(2)? as usize)),
            0xdd => return Ok(Item::Array(self.uint(4)? as usize)),
            0xde => return Ok(Item::Map(self.uint(2)? as usize)),
            0xdf => return Ok(Item::Map(self.uint(4)? as usize)),
            0xe0..=0xff => Value::from(i64::from(marker as i8)),
        };
        Ok(Item::Value(value))
    }

    fn string(&mut self, n: usize) -> Result<Value, WireError> {
        if n > MAX_DETAIL_LEN {
            return Err(WireError::with_limit(
                ErrorCode::LimitExceeded,
                "max_detail_len",
                format!("a string of {n} bytes exceeds max_detail_len={MAX_DETAIL_LEN}, the longest string field"),
            ));
        }
        let bytes = self.take(n)?;
        let text = std::str::from_utf8(bytes)
            .map_err(|err| WireError::malformed(format!("invalid UTF-8 in a string: {err}")))?;
        Ok(Value::String(Utf8String::from(text)))
    }

    fn binary(&mut self, width: usize) -> Result<Value, WireError> {
        let n = self.uint(width)? as usize;
        if n > 0 {
            return Err(WireError::invalid(
                "a msgpack bin value: lessmap messages use no binary or extension types",
            ));
        }
        Ok(Value::Binary(Vec::new()))
    }

    fn ext(&mut self, width: usize) -> Result<Value, WireError> {
        let n = self.uint(width)? as usize;
        self.ext_data(n)
    }

    fn ext_data(&mut self, n: usize) -> Result<Value, WireError> {
        if n > 0 {
            return Err(WireError::invalid(
                "a msgpack ext value: lessmap messages use no binary or extension types",
            ));
        }
        let tag = self.take(1)?[0] as i8;
        Ok(Value::Ext(tag, Vec::new()))
    }
}

/// What `Reader::item` read.
enum Item {
    Value(Value),
    Array(usize),
    Map(usize),
}

/// A container being read: its items so far and how many it has; a map's pending key.
enum Open {
    Array(Vec<Value>, usize),
    Map(Vec<(Value, Value)>, usize, Option<Value>),
}

/// Map keys are msgpack str; a bin key is a bin value (INVALID), anything else MALFORMED.
fn check_key(key: &Value) -> Result<(), WireError> {
    match key {
        Value::String(_) => Ok(()),
        Value::Binary(_) => Err(WireError::invalid("a msgpack bin map key")),
        other => Err(WireError::malformed(format!(
            "a map key is a msgpack {}, not a str",
            kind_of(other)
        ))),
    }
}

//! The checks of the messages' `validate` that serde cannot make: ranges, names and
//! consistency, each failure with the code the contract gives it (sections 5 and 8) and a
//! message naming the field by its path (`Transition.closed.last_seq`).

use crate::error::{ErrorCode, WireError};
use crate::names::PARTITIONS;

/// Largest seq and counter: the largest integer a JavaScript number holds exactly.
pub const MAX_SEQ: u64 = (1 << 53) - 1;
/// Largest feature ID: fits a signed 64-bit integer.
pub const MAX_FEATURE_ID: u64 = (1 << 63) - 1;

/// Field checks labelled by the field's path, so a label cannot drift from its field; in the
/// order given, which is the order a message's checks report in.
///
/// * `check!(self, names: fleet, robot)`: `validate_name(&self.fleet, "fleet")?`, ...;
///   `names?:` skips a `None`.
/// * `check!(self, "Frame", seq: seq, ...)`: `seq(self.seq, "Frame.seq")?`, ...; `seq?:`
///   skips a `None`. A path that is not a literal (a nested item's) is formatted at run time.
macro_rules! check {
    ($item:expr, names: $($field:ident),+) => {
        $($crate::names::validate_name(&$item.$field, stringify!($field))?;)+
    };
    ($item:expr, names?: $($field:ident),+) => {
        $(if let Some(value) = &$item.$field {
            $crate::names::validate_name(value, stringify!($field))?;
        })+
    };
    ($item:expr, $at:literal, $check:ident?: $($field:ident),+) => {
        $(if let Some(value) = $item.$field {
            $check(value, concat!($at, ".", stringify!($field)))?;
        })+
    };
    ($item:expr, $at:literal, $check:ident: $($field:ident),+) => {
        $($check($item.$field, concat!($at, ".", stringify!($field)))?;)+
    };
    ($item:expr, $at:expr, $check:ident: $($field:ident),+) => {
        $($check($item.$field, &format!("{}.{}", $at, stringify!($field)))?;)+
    };
}

pub(crate) fn invalid(message: String) -> WireError {
    WireError::new(ErrorCode::Invalid, message)
}

/// An `INVALID` failure with `message` unless `holds` (the message is built only on failure).
pub(crate) fn ensure(holds: bool, message: impl FnOnce() -> String) -> Result<(), WireError> {
    if holds {
        Ok(())
    } else {
        Err(invalid(message()))
    }
}

/// A seq: at most `MAX_SEQ`, else `LIMIT_EXCEEDED` (`max_seq`).
pub(crate) fn seq(value: u64, field: &str) -> Result<(), WireError> {
    if value > MAX_SEQ {
        return Err(WireError::with_limit(
            ErrorCode::LimitExceeded,
            "max_seq",
            format!("{field}={value} exceeds max_seq={MAX_SEQ}"),
        ));
    }
    Ok(())
}

/// A count or an id: at most 2**53-1.
pub(crate) fn count(value: u64, field: &str) -> Result<(), WireError> {
    ensure(value <= MAX_SEQ, || {
        format!("{field}={value} is above 2**53-1")
    })
}

/// A count that cannot be 0, or an epoch: in 1..2**53-1.
pub(crate) fn positive(value: u64, field: &str) -> Result<(), WireError> {
    ensure(value != 0 && value <= MAX_SEQ, || {
        format!("{field}={value} is not in 1..2**53-1")
    })
}

pub(crate) fn features(values: &[u64], field: &str) -> Result<(), WireError> {
    match values.iter().find(|id| **id > MAX_FEATURE_ID) {
        Some(big) => Err(feature_limit(*big, field)),
        None => Ok(()),
    }
}

pub(crate) fn feature_limit(id: u64, field: &str) -> WireError {
    WireError::with_limit(
        ErrorCode::LimitExceeded,
        "max_feature_id",
        format!("{field} holds {id}; max_feature_id={MAX_FEATURE_ID}"),
    )
}

pub(crate) fn finite(value: f64, field: &str) -> Result<(), WireError> {
    ensure(value.is_finite(), || {
        format!("{field} must be finite, not {value}")
    })
}

pub(crate) fn non_negative(value: f64, field: &str) -> Result<(), WireError> {
    finite(value, field)?;
    ensure(value >= 0.0, || {
        format!("{field} must be >= 0, not {value}")
    })
}

pub(crate) fn partition(value: u16, field: &str) -> Result<(), WireError> {
    ensure(value < PARTITIONS, || {
        format!("{field}={value} is not in 0..{}", PARTITIONS - 1)
    })
}

/// A span of frames: `first_seq <= last_seq`.
pub(crate) fn seq_span(first_seq: u64, last_seq: u64, at: &str) -> Result<(), WireError> {
    ensure(first_seq <= last_seq, || {
        format!("{at}: first_seq {first_seq} is after last_seq {last_seq}")
    })
}

/// Validate each item of a nested list, labelled `<at>.<index>`.
pub(crate) fn each<T>(
    items: &[T],
    at: &str,
    validate: impl Fn(&T, &str) -> Result<(), WireError>,
) -> Result<(), WireError> {
    for (index, item) in items.iter().enumerate() {
        validate(item, &format!("{at}.{index}"))?;
    }
    Ok(())
}
pub(crate) use check;

//! Names, key expressions and partitions (contract sections 2, 2a and 3).
//!
//! Every key a robot or a fleet app uses is built here, so a name that breaks the rule never
//! reaches Zenoh: `*` is accepted only where the contract allows a wildcard chunk.

use sha2::{Digest, Sha256};

use crate::error::{ErrorCode, WireError};

/// Value of the `v` field of every message and of the `v4` key chunk.
pub const WIRE_VERSION: u64 = 4;
/// First two chunks of every key; the version chunk is `v` followed by [`WIRE_VERSION`].
pub const KEY_PREFIX: &str = "lessmap/v4";
/// Number of partitions; fixed by the contract version.
pub const PARTITIONS: u16 = 256;
/// Longest fleet, robot, session or instance name (a format bound).
pub const MAX_NAME_LEN: usize = 64;
/// A whole-chunk wildcard, for subscriptions and queries only.
pub const ANY: &str = "*";

/// Check a fleet, robot, session or instance name (`what` names it in the error).
///
/// The rule: 1 to 64 characters, ASCII letters, digits, `_`, `.` and `-`, not starting with
/// `.` or `-`. A break is a [`WireError`] with code `BAD_NAME` (and limit `max_name_len` when
/// the name is too long).
pub fn validate_name(value: &str, what: &str) -> Result<(), WireError> {
    // Characters, not bytes, as the reference reader counts them.
    if value.chars().count() > MAX_NAME_LEN {
        let shown: String = value.chars().take(80).collect();
        return Err(WireError::with_limit(
            ErrorCode::BadName,
            "max_name_len",
            format!("{what} name {shown:?} is longer than {MAX_NAME_LEN} characters"),
        ));
    }
    let mut chars = value.chars();
    let Some(first) = chars.next() else {
        return Err(WireError::new(
            ErrorCode::BadName,
            format!("{what} name is empty"),
        ));
    };
    if !(first.is_ascii_alphanumeric() || first == '_') {
        return Err(WireError::new(
            ErrorCode::BadName,
            format!("{what} name {value:?} starts with {first:?}; a name starts with a letter, digit or '_'"),
        ));
    }
    if let Some((index, bad)) = value
        .chars()
        .enumerate()
        .find(|(_, c)| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-')))
    {
        return Err(WireError::new(
            ErrorCode::BadName,
            format!("{what} name {value:?} has {bad:?} at index {index}; allowed are ASCII letters, digits, '_', '.' and '-'"),
        ));
    }
    Ok(())
}

fn chunk<'a>(value: &'a str, what: &str) -> Result<&'a str, WireError> {
    if value != ANY {
        validate_name(value, what)?;
    }
    Ok(value)
}

fn u64_of(text: &str) -> u64 {
    let digest = Sha256::digest(text.as_bytes());
    let mut head = [0u8; 8];
    head.copy_from_slice(&digest[..8]);
    u64::from_be_bytes(head)
}

/// The partition of a robot: `u64(SHA-256(fleet + "/" + robot)[0..8]) mod 256`.
pub fn partition_of(fleet: &str, robot: &str) -> u16 {
    // The remainder is below 256, so the cast cannot truncate.
    (u64_of(&format!("{fleet}/{robot}")) % u64::from(PARTITIONS)) as u16
}

/// The rendezvous weight of a service instance for a partition.
pub fn score(instance: &str, partition: u16) -> u64 {
    u64_of(&format!("{instance}/{partition}"))
}

/// The instances in the order they would serve a partition: owner, standby, ...
///
/// Highest score first, ties by name ascending; duplicates are removed.
pub fn ranking<S: AsRef<str>>(partition: u16, instances: &[S]) -> Vec<String> {
    let mut names: Vec<String> = instances.iter().map(|s| s.as_ref().to_owned()).collect();
    names.sort();
    names.dedup();
    names.sort_by_cached_key(|name| (std::cmp::Reverse(score(name, partition)), name.clone()));
    names
}

/// The owner and the standby of a partition among live instances (`None` if absent).
pub fn owner_and_standby<S: AsRef<str>>(
    partition: u16,
    instances: &[S],
) -> (Option<String>, Option<String>) {
    let mut ranked = ranking(partition, instances).into_iter();
    (ranked.next(), ranked.next())
}

/// Key expressions of every lessmap stream, one function per stream.
pub mod keys {
    use super::{chunk, partition_of, validate_name, ANY, KEY_PREFIX};
    use crate::error::WireError;

    fn robot_key(fleet: &str, robot: &str, stream: &str) -> Result<String, WireError> {
        Ok(format!(
            "{KEY_PREFIX}/{}/{}/{stream}",
            chunk(fleet, "fleet")?,
            chunk(robot, "robot")?
        ))
    }

    /// `lessmap/v4/<fleet>/<robot>/frames/<p>`: where a robot puts `Frame` and `SessionEnd`.
    ///
    /// With a wildcard fleet or robot the partition chunk is a wildcard too.
    pub fn frames(fleet: &str, robot: &str) -> Result<String, WireError> {
        let key = robot_key(fleet, robot, "frames")?;
        if fleet == ANY || robot == ANY {
            return Ok(format!("{key}/{ANY}"));
        }
        Ok(format!("{key}/{}", partition_of(fleet, robot)))
    }

    /// `lessmap/v4/<fleet>/<robot>/transitions` (`*` allowed for either name).
    pub fn transitions(fleet: &str, robot: &str) -> Result<String, WireError> {
        robot_key(fleet, robot, "transitions")
    }

    /// `lessmap/v4/<fleet>/<robot>/errors` (`*` allowed for either name).
    pub fn errors(fleet: &str, robot: &str) -> Result<String, WireError> {
        robot_key(fleet, robot, "errors")
    }

    /// `lessmap/v4/<fleet>/<robot>/state`, answered with a `SessionState`.
    pub fn state(fleet: &str, robot: &str) -> Result<String, WireError> {
        robot_key(fleet, robot, "state")
    }

    /// `lessmap/v4/<fleet>/<robot>/areas`, answered with an `AreaGraph`.
    pub fn areas(fleet: &str, robot: &str) -> Result<String, WireError> {
        robot_key(fleet, robot, "areas")
    }

    /// `lessmap/v4/<fleet>/<robot>/submaps/<id>`, answered with a `Submap`.
    pub fn submap(fleet: &str, robot: &str, submap_id: u64) -> Result<String, WireError> {
        Ok(format!(
            "{}/{submap_id}",
            robot_key(fleet, robot, "submaps")?
        ))
    }

    /// `lessmap/v4/<fleet>/<robot>/submaps/*`: every submap of the robot's session.
    pub fn submaps(fleet: &str, robot: &str) -> Result<String, WireError> {
        Ok(format!("{}/{ANY}", robot_key(fleet, robot, "submaps")?))
    }

    /// `lessmap/v4/@/instances/<instance>`: the liveliness token of a service instance.
    pub fn instance_token(instance: &str) -> Result<String, WireError> {
        validate_name(instance, "instance")?;
        Ok(format!("{KEY_PREFIX}/@/instances/{instance}"))
    }

    /// `lessmap/v4/@/instances/*`: every instance token.
    pub fn instances() -> String {
        format!("{KEY_PREFIX}/@/instances/{ANY}")
    }

    /// `lessmap/v4/@/health/<instance>` (`*` for every instance), answered with `Health`.
    pub fn health(instance: &str) -> Result<String, WireError> {
        Ok(format!(
            "{KEY_PREFIX}/@/health/{}",
            chunk(instance, "instance")?
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_key_prefix_carries_the_wire_version() {
        assert_eq!(KEY_PREFIX, format!("lessmap/v{WIRE_VERSION}"));
    }

    #[test]
    fn robot_keys_take_names_or_whole_chunk_wildcards() {
        assert_eq!(
            keys::areas("warehouse", "amr-7").unwrap(),
            "lessmap/v4/warehouse/amr-7/areas"
        );
        assert_eq!(keys::areas("*", "*").unwrap(), "lessmap/v4/*/*/areas");
        assert_eq!(
            keys::areas("warehouse", "amr/7").unwrap_err().code,
            ErrorCode::BadName
        );
        assert_eq!(
            keys::state("warehouse", "amr-7").unwrap(),
            "lessmap/v4/warehouse/amr-7/state"
        );
    }
}

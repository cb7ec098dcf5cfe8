//! The golden vectors of `schemas/vectors/`, read where the Python tests read them.
//!
//! Every valid payload must decode to its `json` (and re-encode byte for byte when
//! `canonical`), every invalid one must fail with its `code` and `limit`, and the partition
//! functions must give the pinned partitions, scores and rankings.

use std::collections::BTreeSet;
use std::path::PathBuf;

use lessmap_client::codec::{decode, encode};
use lessmap_client::names::{partition_of, ranking, score, PARTITIONS};
use lessmap_client::{Error, Frame, Health, Message, SessionEnd, SessionState, Submap, Transition};
use serde_json::Value;

fn vectors_dir() -> PathBuf {
    // Read at run time, not baked in with env!(): the build cache is shared by every clone
    // on a machine, and a test binary built in another clone must still read this one's files.
    let crate_dir = std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(
        || std::env::current_dir().expect("a current directory"),
        PathBuf::from,
    );
    crate_dir.join("../../schemas/vectors")
}

fn load(name: &str) -> Value {
    let path = vectors_dir().join(format!("{name}.json"));
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|err| panic!("cannot read {}: {err}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|err| panic!("{}: {err}", path.display()))
}

fn unhex(text: &str) -> Vec<u8> {
    assert!(text.len().is_multiple_of(2), "odd hex length");
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).expect("hex digits"))
        .collect()
}

/// Check one message type's file; return how many vectors were checked.
fn check<M: Message>() -> usize {
    let file = load(M::TYPE);
    assert_eq!(file["type"], M::TYPE);
    let mut failures = Vec::new();
    let valid = file["valid"].as_array().expect("valid list");
    let invalid = file["invalid"].as_array().expect("invalid list");
    for case in valid {
        let name = case["name"].as_str().unwrap();
        let payload = unhex(case["hex"].as_str().unwrap());
        match decode::<M>(&payload) {
            Err(err) => failures.push(format!("{name}: rejected valid payload: {err}")),
            Ok(message) => {
                let json = serde_json::to_value(&message).expect("json");
                if json != case["json"] {
                    failures.push(format!(
                        "{name}: decoded to {json}, expected {}",
                        case["json"]
                    ));
                }
                let canonical = case["canonical"].as_bool().unwrap();
                if (encode(&message) == payload) != canonical {
                    failures.push(format!(
                        "{name}: re-encoding, canonical={canonical} disagrees"
                    ));
                }
            }
        }
    }
    for case in invalid {
        let name = case["name"].as_str().unwrap();
        let payload = unhex(case["hex"].as_str().unwrap());
        let code = case["code"].as_str().unwrap();
        let limit = case["limit"].as_str();
        match decode::<M>(&payload) {
            Ok(message) => failures.push(format!("{name}: accepted, expected {code}: {message:?}")),
            Err(err) if (err.code.as_str(), err.limit) != (code, limit) => failures.push(format!(
                "{name}: got {}/{:?} ({}), expected {code}/{limit:?}",
                err.code, err.limit, err.message
            )),
            Err(_) => {}
        }
    }
    assert!(
        failures.is_empty(),
        "{} vectors failed:\n{}",
        M::TYPE,
        failures.join("\n")
    );
    valid.len() + invalid.len()
}

#[test]
fn every_vector_file_is_checked() {
    let mut files = BTreeSet::new();
    for entry in std::fs::read_dir(vectors_dir()).expect("schemas/vectors") {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|ext| ext == "json") {
            files.insert(path.file_stem().unwrap().to_string_lossy().into_owned());
        }
    }
    let known: BTreeSet<String> = [
        Frame::TYPE,
        SessionEnd::TYPE,
        Transition::TYPE,
        Error::TYPE,
        SessionState::TYPE,
        Submap::TYPE,
        Health::TYPE,
        "partition",
    ]
    .into_iter()
    .map(String::from)
    .collect();
    assert_eq!(files, known, "a vector file this test does not read");
}

#[test]
fn frame_vectors() {
    assert!(check::<Frame>() > 50);
}

#[test]
fn session_end_vectors() {
    assert!(check::<SessionEnd>() > 30);
}

#[test]
fn transition_vectors() {
    assert!(check::<Transition>() > 30);
}

#[test]
fn error_vectors() {
    assert!(check::<Error>() > 30);
}

#[test]
fn session_state_vectors() {
    assert!(check::<SessionState>() > 30);
}

#[test]
fn submap_vectors() {
    assert!(check::<Submap>() > 30);
}

#[test]
fn health_vectors() {
    assert!(check::<Health>() > 30);
}

#[test]
fn partition_vectors() {
    let file = load("partition");
    assert_eq!(file["partitions"], u64::from(PARTITIONS));
    let robots = file["robots"].as_array().unwrap();
    assert!(!robots.is_empty());
    for case in robots {
        let (fleet, robot) = (
            case["fleet"].as_str().unwrap(),
            case["robot"].as_str().unwrap(),
        );
        assert_eq!(
            u64::from(partition_of(fleet, robot)),
            case["partition"],
            "{fleet}/{robot}"
        );
    }
    for case in file["scores"].as_array().unwrap() {
        let instance = case["instance"].as_str().unwrap();
        let p = u16::try_from(case["partition"].as_u64().unwrap()).unwrap();
        assert_eq!(
            format!("{:016x}", score(instance, p)),
            case["score_hex"],
            "{instance}/{p}"
        );
    }
    for case in file["rankings"].as_array().unwrap() {
        let p = u16::try_from(case["partition"].as_u64().unwrap()).unwrap();
        let live: Vec<&str> = case["instances"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap())
            .collect();
        let expected: Vec<&str> = case["ranking"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap())
            .collect();
        assert_eq!(ranking(p, &live), expected, "partition {p} over {live:?}");
    }
}

//! The golden vectors of `schemas/vectors/`, read where the Python tests read them.
//!
//! Every valid payload must decode to its `json` (and re-encode byte for byte when
//! `canonical`), every invalid one must fail with its `code` and `limit`, and the partition
//! functions must give the pinned partitions, scores and rankings.

use std::collections::BTreeSet;
use std::path::PathBuf;

use lessmap_client::codec::{decode, encode};
use lessmap_client::fleet_areas::{fleet_graph, FleetParams};
use lessmap_client::names::{partition_of, ranking, score, PARTITIONS};
use lessmap_client::query::current_area_graphs;
use lessmap_client::{
    end_progress, AreaGraph, EndProgress, Error, Frame, Health, Message, Method, Reason,
    SessionEnd, SessionState, Submap, Transition,
};
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
        AreaGraph::TYPE,
        Health::TYPE,
        "partition",
        "fleet_areas",
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
fn area_graph_vectors() {
    assert!(check::<AreaGraph>() > 50);
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

/// The decoded message of the valid vector `name` of `M`'s file.
fn valid_vector<M: Message>(name: &str) -> M {
    let file = load(M::TYPE);
    let case = file["valid"]
        .as_array()
        .unwrap()
        .iter()
        .find(|case| case["name"] == name)
        .unwrap_or_else(|| panic!("no {} vector {name:?}", M::TYPE));
    decode::<M>(&unhex(case["hex"].as_str().unwrap())).expect("a valid vector")
}

/// The decoded `SessionState` of the valid vector `name`.
fn state_vector(name: &str) -> SessionState {
    valid_vector(name)
}

#[test]
fn v4_fields_decode_to_their_types() {
    let recognised: Transition = valid_vector("recognised revisit");
    assert_eq!(recognised.reason, Reason::Recognised);
    assert!(recognised.revisit && recognised.ncut.is_none() && recognised.lambda2.is_none());
    assert_ne!(recognised.area, recognised.left_area);
    let state: SessionState = valid_vector("method areas");
    assert_eq!(state.method, Method::Areas);
    let graph: AreaGraph = valid_vector("typical");
    assert_eq!(graph.method, Method::Areas);
    let ids: Vec<u64> = graph.areas.iter().map(|area| area.id).collect();
    assert_eq!(ids, [0, 2]); // a merged id is not used again
    assert_eq!(graph.area(2).map(|area| area.visits), Some(1));
    assert!(graph.area(1).is_none());
    assert_eq!(graph.passages[0].boundary_features, [(3, 2), (2, 1)]);
    assert_eq!(graph.total_frames(), 57);
    let empty: AreaGraph = valid_vector("no frames yet");
    assert!(empty.areas.is_empty() && empty.passages.is_empty());
    assert_eq!(empty.total_frames(), 0);
}

#[test]
fn one_area_graph_per_robot_the_highest_epoch_then_the_most_frames() {
    let typical: AreaGraph = valid_vector("typical");
    let mut fewer_frames = typical.clone();
    fewer_frames.areas[0].frames -= 1;
    fewer_frames.instance = "fewer".into();
    let mut older = typical.clone();
    older.epoch -= 1;
    older.areas[0].frames += 100;
    older.instance = "older".into();
    let mut other_robot = older.clone();
    other_robot.robot = "amr-1".into();
    let kept = |graphs: &[&AreaGraph]| -> Vec<(String, String)> {
        current_area_graphs(graphs.iter().map(|g| (*g).clone()).collect())
            .into_iter()
            .map(|g| (g.robot, g.instance))
            .collect()
    };
    let robot = typical.robot.clone();
    let (a1, current) = ("amr-1".to_owned(), typical.instance.clone());
    // The higher epoch wins over more frames, whatever the order of the replies.
    assert_eq!(
        kept(&[&older, &typical]),
        [(robot.clone(), current.clone())]
    );
    assert_eq!(
        kept(&[&typical, &older]),
        [(robot.clone(), current.clone())]
    );
    // One epoch: more frames win; robots by name.
    assert_eq!(
        kept(&[&fewer_frames, &other_robot, &typical]),
        [
            (a1.clone(), "older".into()),
            (robot.clone(), current.clone())
        ]
    );
    assert_eq!(kept(&[&typical, &fewer_frames]), [(robot.clone(), current)]);
    assert!(kept(&[]).is_empty());
}

#[test]
fn close_confirmation_follows_the_newest_state_of_the_session() {
    use EndProgress::{CaughtUp, Closed, Pending};
    let open = state_vector("typical"); // open, last_seq 42
    let closed = state_vector("closed, no frames yet"); // closed, no frame applied
    assert!(open.open && open.last_seq == Some(42) && !closed.open);
    let (fleet, robot, session) = (open.fleet.clone(), open.robot.clone(), open.session.clone());
    let progress = |replies: &[&SessionState], session: &str, last_seq: u64| {
        let replies = replies.iter().map(|s| (*s).clone()).collect();
        end_progress(replies, &fleet, &robot, session, last_seq)
    };

    // Open: caught up once every frame up to the end's last seq is applied.
    assert_eq!(progress(&[&open], &session, 42), CaughtUp);
    assert_eq!(progress(&[&open], &session, 7), CaughtUp);
    assert_eq!(progress(&[&open], &session, 43), Pending);
    let mut empty = open.clone();
    empty.last_seq = None;
    assert_eq!(progress(&[&empty], &session, 0), Pending);
    // Closed: confirmed whatever was applied.
    assert_eq!(progress(&[&closed], &session, 99), Closed);
    // No state (a take-over in progress), another session, another robot: not confirmed.
    assert_eq!(progress(&[], &session, 0), Pending);
    assert_eq!(progress(&[&closed], "another-session", 0), Pending);
    let mut other_robot = closed.clone();
    other_robot.robot = "amr-8".into();
    assert_eq!(progress(&[&other_robot], &session, 0), Pending);

    // A hand-over: the newest epoch decides, whatever the order of the replies.
    let mut deposed_closed = closed.clone();
    deposed_closed.epoch = open.epoch - 1;
    let mut current_behind = open.clone();
    current_behind.last_seq = Some(40);
    assert_eq!(
        progress(&[&deposed_closed, &current_behind], &session, 42),
        Pending
    );
    assert_eq!(
        progress(&[&current_behind, &deposed_closed], &session, 40),
        CaughtUp
    );
    let mut deposed_open = open.clone();
    deposed_open.epoch = closed.epoch - 1;
    assert_eq!(progress(&[&deposed_open, &closed], &session, 42), Closed);
}

#[test]
fn fleet_area_vectors() {
    // The Python SDK checks the same file (tests/client/test_fleet_areas.py): one merge.
    let file = load("fleet_areas");
    let cases = file["cases"].as_array().unwrap();
    assert!(cases.len() >= 10);
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let p = &case["params"];
        let params = FleetParams {
            shared_features: p["shared_features"].as_bool().unwrap(),
            min_containment: p["min_containment"].as_f64().unwrap(),
            min_shared: p["min_shared"].as_u64().unwrap(),
            min_linked_share: p["min_linked_share"].as_f64().unwrap(),
            max_boundary_features: usize::try_from(p["max_boundary_features"].as_u64().unwrap())
                .unwrap(),
        };
        let graphs: Vec<AreaGraph> = case["graphs_hex"]
            .as_array()
            .unwrap()
            .iter()
            .map(|h| decode::<AreaGraph>(&unhex(h.as_str().unwrap())).expect(name))
            .collect();
        let fleet = fleet_graph(&graphs, &params).expect(name);
        let nodes: Vec<Value> = fleet
            .nodes
            .iter()
            .map(|n| {
                serde_json::json!({
                    "area": n.area,
                    "members": n.members.iter().map(|(r, a)| serde_json::json!([r, a])).collect::<Vec<_>>(),
                    "frames": n.frames,
                    "visits": n.visits,
                    "features": n.features,
                })
            })
            .collect();
        assert_eq!(Value::from(nodes), case["fleet"]["nodes"], "{name}: nodes");
        let edges: Vec<Value> = fleet
            .edges
            .iter()
            .map(|e| {
                serde_json::json!({
                    "a": e.a,
                    "b": e.b,
                    "a_to_b": e.a_to_b,
                    "b_to_a": e.b_to_a,
                    "robots": e.robots,
                    "boundary_features": e.boundary_features.iter().map(|(f, n)| serde_json::json!([f, n])).collect::<Vec<_>>(),
                })
            })
            .collect();
        assert_eq!(Value::from(edges), case["fleet"]["edges"], "{name}: edges");
        let area_of: Vec<Value> = fleet
            .area_of
            .iter()
            .map(|((r, a), f)| serde_json::json!([r, a, f]))
            .collect();
        assert_eq!(
            Value::from(area_of),
            case["fleet"]["area_of"],
            "{name}: area_of"
        );
    }
}

#[test]
fn fleet_merge_refuses_mixed_input() {
    let file = load("fleet_areas");
    let case = &file["cases"][0];
    let graph: AreaGraph = decode(&unhex(case["graphs_hex"][0].as_str().unwrap())).unwrap();
    let twice = [graph.clone(), graph.clone()];
    let err = fleet_graph(&twice, &FleetParams::default()).unwrap_err();
    assert!(
        err.to_string().contains("two area graphs for robot"),
        "{err}"
    );
    let mut other = graph.clone();
    other.fleet = "elsewhere".to_owned();
    other.robot = "r9".to_owned();
    let err = fleet_graph(&[graph, other], &FleetParams::default()).unwrap_err();
    assert!(err.to_string().contains("several fleets"), "{err}");
    let bad = FleetParams {
        min_containment: 0.0,
        ..FleetParams::shared()
    };
    assert!(fleet_graph(&[], &bad).is_err());
}

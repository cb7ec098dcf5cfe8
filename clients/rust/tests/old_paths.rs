//! Types that moved between modules still resolve at their old paths, as the same types.

use lessmap_client::codec::{ErrorCode, WireError};
use lessmap_client::connection::{current_states, ClientError, OwnerAndStandby};
use lessmap_client::fleet_areas::FleetMergeError;
use lessmap_client::robot::{end_progress, EndProgress};

#[test]
fn moved_types_keep_their_old_paths() {
    let wire: lessmap_client::error::WireError = WireError::new(ErrorCode::SeqGap, "gap");
    let client: lessmap_client::ClientError = ClientError::from(wire);
    assert_eq!(client.to_string(), "SEQ_GAP: gap");
    let merge: lessmap_client::FleetMergeError = FleetMergeError::DuplicateRobot("r".into());
    assert!(merge.to_string().contains("two area graphs for robot"));
    let progress: lessmap_client::closing::EndProgress = end_progress(Vec::new(), "f", "r", "s", 0);
    assert_eq!(progress, EndProgress::Pending);
    assert!(current_states(Vec::new()).is_empty());
    let nobody: OwnerAndStandby = (None, None);
    assert_eq!(nobody, lessmap_client::query::OwnerAndStandby::default());
}

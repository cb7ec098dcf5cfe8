"""ID paths: which fields of a ROS message are feature IDs."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from lessmap.errors import ConfigError
from lessmap.ros.extract import DEFAULT_ID_PATHS, feature_id, parse_id_options, parse_id_path
from tests.ros.conftest import (
    APRILTAG,
    ARUCO,
    MARKERS,
    apriltag_array,
    aruco_markers,
    marker_array,
)

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore


def test_the_built_in_paths_read_the_three_detector_types(store: Typestore) -> None:
    paths = {name: parse_id_path(text) for name, text in DEFAULT_ID_PATHS.items()}
    assert paths[APRILTAG].ids(apriltag_array(store, [4, 9, 4], 1.0)) == [4, 9, 4]
    assert paths[ARUCO].ids(aruco_markers(store, [7, 2], 1.0)) == [7, 2]
    markers = marker_array(store, [("walls", 1, 0), ("walls", 2, 2), ("", 0, 3)], 1.0)
    assert paths[MARKERS].ids(markers) == [feature_id(["walls", 1])]  # ADD only


def test_ids_survive_a_cdr_round_trip(store: Typestore) -> None:
    message = apriltag_array(store, [1, 2, 3], 12.5)
    decoded = store.deserialize_cdr(bytes(store.serialize_cdr(message, APRILTAG)), APRILTAG)
    assert parse_id_path("detections[].id").ids(decoded) == [1, 2, 3]


def test_feature_ids_are_stable_and_in_range() -> None:
    assert feature_id(5) == 5
    assert feature_id(2**63 - 1) == 2**63 - 1
    # Hashes are fixed forever: live and offline runs, any machine, any version.
    assert feature_id("door-3") == 4087074199707837049
    assert feature_id(["walls", 1]) == 2340009431907672519
    for value in (-1, 2**63, "x", ["ns", 3]):
        assert 0 <= feature_id(value) <= 2**63 - 1
    with pytest.raises(ValueError, match="not a feature ID"):
        feature_id(1.5)


@pytest.mark.parametrize("bad", ["id", "x[", "a[]b", "a..b", ""])
def test_a_bad_path_is_one_clear_error(bad: str) -> None:
    with pytest.raises(ConfigError, match="ID path"):
        parse_id_path(bad)


def test_options_override_and_extend_the_defaults() -> None:
    paths = parse_id_options([f"{ARUCO}=marker_ids[]", "my_msgs/msg/Seen=items[].name"])
    assert paths["my_msgs/msg/Seen"].leaf == ("name",)
    assert set(DEFAULT_ID_PATHS) <= set(paths)
    with pytest.raises(ConfigError, match="TYPE=PATH"):
        parse_id_options(["marker_ids[]"])
    with pytest.raises(ConfigError, match="not a ROS message type name"):
        parse_id_options(["Markers=x[]"])

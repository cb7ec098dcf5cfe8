"""The "why" figures: stream density, equal-count baselines, true-room labels."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from lessmap.core import PartitionParams
from lessmap.evaluation.baselines import fixed_features
from lessmap.evaluation.data.dataset import load_dataset
from lessmap.evaluation.scores.infoloss import landmark_information
from lessmap.evaluation.studies.diagnosis import (
    count_curve,
    limit_for_count,
    off_diagonal_share,
    room_labels,
    stream_stats,
    variant_row,
)
from lessmap.files.frames import FrameRow
from lessmap.sim.building import Door
from lessmap.sim.simulator import RoomChange, SimTruth, TruthRow
from tests.evaluation.helpers import write_dataset

if TYPE_CHECKING:
    from pathlib import Path


def test_stream_stats_by_hand() -> None:
    # feature 1 in view for frames 0-2, then again at 4; feature 2 at frame 1 only.
    stats = stream_stats([[1], [1, 2], [1], [], [1]])
    assert stats.frames == 5
    assert stats.features_mean == pytest.approx(1.0)
    assert stats.empty_share == pytest.approx(0.2)
    assert stats.sightings_median == pytest.approx(2.5)  # 4 and 1 sightings
    assert stats.run_mean == pytest.approx(5 / 3)  # runs of 3, 1 and 1 frames
    assert stats.run_median == 1.0


def test_limit_for_count_finds_the_nearest_count() -> None:
    frames = [[k, k + 1000] for k in range(100)]  # two new features per frame
    for count in (1, 5, 10, 33):
        limit = limit_for_count(frames, count)
        made = int(fixed_features(frames, limit).max()) + 1
        assert abs(made - count) <= 1, (count, limit, made)


def test_variant_row_sets_lessmap_against_equal_counts(tmp_path: Path) -> None:
    dataset = load_dataset(write_dataset(tmp_path))
    info = landmark_information(dataset.problem)
    row = variant_row("paper", dataset.frames, info, PartitionParams.from_profile("laser"))
    assert row.lessmap.submaps == 2
    assert row.fixed_frames.submaps == 2
    assert abs(row.fixed_features.submaps - 2) <= 1
    assert row.spectral + row.disconnected == 1
    assert 0.0 <= row.lessmap.e <= row.lessmap.e_exclusive <= 1.0
    with pytest.raises(ValueError, match="params or a run"):
        variant_row("nothing", dataset.frames, info)
    curve = count_curve([f.features for f in dataset.frames], info, "frames", [60, 30, 10])
    assert [x.submaps for x in curve] == [1, 2, 6]
    assert curve[0].e == 0.0
    assert curve[1].e < curve[2].e
    assert 0.0 < off_diagonal_share(info) < 1.0


def test_room_labels_per_visit_and_merged() -> None:
    rooms = [0, 0, 1, 1, 0, 2]
    truth = SimTruth(
        rows=tuple(TruthRow("r", k, k / 2, room, 0.0, 0.0, 0, 1.0) for k, room in enumerate(rooms)),
        doors=(Door(0, 0.0, 0.0, (0, 1), 1.0, vertical=True),),
        changes=(RoomChange("r", 2, 0, 1, 0),),
    )
    frames = [FrameRow("r", k, float(k), (), None) for k in range(len(rooms))]
    np.testing.assert_array_equal(room_labels(frames, truth, merged=False), [0, 0, 1, 1, 2, 3])
    np.testing.assert_array_equal(room_labels(frames, truth, merged=True), [0, 0, 1, 1, 0, 2])

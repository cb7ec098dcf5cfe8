"""The whole evaluation on the real DLR data set (skipped where ../shared/datasets is absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

from lessmap.core import PartitionParams
from lessmap.evaluation.data.dataset import load_dataset
from lessmap.evaluation.report.evaluation import evaluate

DATASETS = Path(__file__).resolve().parents[2] / ".." / "shared" / "datasets"
DLR = DATASETS / "dlr.frames.jsonl"


@pytest.mark.slow
@pytest.mark.skipif(not DLR.is_file(), reason=f"data set not found: {DLR}")
def test_dlr_evaluation() -> None:
    dataset = load_dataset(DLR)
    params = PartitionParams.from_profile("laser")
    # The sweep holds only the main thresholds: their run is reused, not repeated.
    report = evaluate(dataset, params, ncut_values=[0.25], lambda2_values=[0.2])
    assert report.frames == 3297
    assert report.landmarks == 576
    assert report.info.unit_information_edges == 0
    names = [m.name for m in report.methods]
    assert names[0].startswith("lessmap (Ncut≤0.25, λ2≤0.2)")
    assert names[1:3] == ["fixed-50 features", "fixed-60 features"]
    assert names[3].endswith(" frames")
    assert names[4] == "no partition"
    lessmap, fixed50, fixed60, fixed_frames, single = report.methods
    for method in report.methods:
        assert 0.0 <= method.e <= 1.0, method.name
        assert 0.0 <= method.e_exclusive <= 1.0, method.name
    assert lessmap.stats.submaps > 1
    assert fixed_frames.stats.submaps == pytest.approx(lessmap.stats.submaps, rel=0.05)
    assert single.e == 0.0
    assert single.stats.submaps == 1
    assert fixed50.stats.submaps > fixed60.stats.submaps > 1
    assert report.sweep[0].e == lessmap.e

"""Threshold sweep over (Ncut_min, λ2_min)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.core import PartitionParams
from lessmap.evaluation.data.dataset import load_dataset
from lessmap.evaluation.data.segmentation import run_lessmap
from lessmap.evaluation.scores.infoloss import landmark_information
from lessmap.evaluation.studies.sweep import format_table, run_grid, sweep
from tests.evaluation.helpers import write_dataset

if TYPE_CHECKING:
    from pathlib import Path


def test_sweep_rows_in_grid_order(tmp_path: Path) -> None:
    dataset = load_dataset(write_dataset(tmp_path))
    info = landmark_information(dataset.problem)
    base = PartitionParams.from_profile("laser")
    rows = sweep(dataset.frames, info, base, [0.1, 0.3], [0.2, 0.4, 0.6])
    assert [(r.ncut_min, r.lambda2_min) for r in rows] == [
        (0.1, 0.2),
        (0.1, 0.4),
        (0.1, 0.6),
        (0.3, 0.2),
        (0.3, 0.4),
        (0.3, 0.6),
    ]
    for row in rows:
        assert 0.0 <= row.e <= 1.0
        assert 0.0 <= row.e_exclusive <= 1.0
        assert row.stats.submaps == row.spectral + row.disconnected + 1
    table = format_table(rows).splitlines()
    assert len(table) == 2 + len(rows)
    assert "Ncut_min" in table[0]


def test_known_runs_are_reused(tmp_path: Path) -> None:
    dataset = load_dataset(write_dataset(tmp_path))
    base = PartitionParams.from_profile("laser")
    made = run_lessmap(dataset.frames, base)
    known = {(0.25, 0.2): made}
    runs = run_grid(dataset.frames, base, [(0.25, 0.2), (0.1, 0.1)], known=known)
    assert runs[(0.25, 0.2)] is made
    assert set(known) == {(0.25, 0.2), (0.1, 0.1)}


def test_worker_processes_give_the_same_runs(tmp_path: Path) -> None:
    dataset = load_dataset(write_dataset(tmp_path))
    base = PartitionParams.from_profile("laser")
    pairs = [(0.1, 0.1), (0.25, 0.2), (0.5, 0.5)]
    here = run_grid(dataset.frames, base, pairs)
    there = run_grid(dataset.frames, base, pairs, jobs=2)
    for pair in pairs:
        assert here[pair].labels.tolist() == there[pair].labels.tolist()
        assert here[pair].transitions == there[pair].transitions

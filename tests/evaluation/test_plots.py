"""PNG figures of a run and of a sweep."""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.core import PartitionParams
from lessmap.evaluation.data.dataset import load_dataset
from lessmap.evaluation.data.segmentation import run_lessmap
from lessmap.evaluation.figures.segmentation import write_plots
from lessmap.evaluation.scores.infoloss import landmark_information
from lessmap.evaluation.studies.sweep import sweep
from lessmap.files.frames import FrameRow
from tests.evaluation.helpers import write_dataset

if TYPE_CHECKING:
    from pathlib import Path

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_plots_are_written_as_png(tmp_path: Path) -> None:
    dataset = load_dataset(write_dataset(tmp_path))
    params = PartitionParams.from_profile("laser")
    run = run_lessmap(dataset.frames, params)
    rows = sweep(
        dataset.frames, landmark_information(dataset.problem), params, [0.1, 0.3], [0.1, 0.3]
    )
    written = write_plots(tmp_path / "png", dataset.frames, run, rows)
    names = {path.name for path in written}
    assert names == {"trajectory.png", "ncut_lambda2.png", "similarity.png", "sweep.png"}
    for path in written:
        data = path.read_bytes()
        assert data.startswith(PNG_MAGIC)
        assert len(data) > 1000


def test_plots_without_poses_or_sweep(tmp_path: Path) -> None:
    frames = [FrameRow("r", k, float(k), (k // 10, k // 10 + 1), None) for k in range(40)]
    run = run_lessmap(frames, PartitionParams.from_profile("laser"))
    written = write_plots(tmp_path, frames, run)
    assert {path.name for path in written} == {"ncut_lambda2.png", "similarity.png"}

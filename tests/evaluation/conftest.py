"""A small simulated run written to files, shared by the evaluation tests."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from lessmap.sim.simulator import SimRun, simulate, write_run

if TYPE_CHECKING:
    from pathlib import Path


@pytest.fixture(scope="session")
def sim_run() -> SimRun:
    """Two robots, four rooms, 150 frames each (seeded)."""
    return simulate(0, rooms=4, robots=2, frames_per_robot=150)


@pytest.fixture(scope="session")
def sim_frames(sim_run: SimRun, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The run's files (frames, truth, building) in a folder; return the frames path."""
    return write_run(sim_run, tmp_path_factory.mktemp("sim"), "sim").frames

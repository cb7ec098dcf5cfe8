"""Smoke test of the service overhead benchmark: tiny sizes, every frame applied, JSON out.

No timing is asserted: the figures depend on the machine.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from benchmarks import service_overhead

if TYPE_CHECKING:
    import pytest


def test_a_tiny_run_applies_every_frame_and_reports_each_part(
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = ["--robots", "3", "--seconds", "2", "--repeats", "1", "--json"]
    assert service_overhead.main(argv) == 0  # the worker asserts every frame was applied
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 60
    assert set(result["us_per_frame"]) == {"core", "worker", "receive"}
    assert all(value > 0 for value in result["us_per_frame"].values())

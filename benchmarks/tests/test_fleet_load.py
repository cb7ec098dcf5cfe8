"""The fleet load benchmark, small: every frame applied, every crossing robot gets its decisions.

Five robots × 10 Hz × 10 features for 5 s through a real ``lessmap serve`` and two generator
processes: once one instance as is, once with batch lingering and two instances on a
``lessmap router`` (each receives exactly its own partitions' frames). Nothing here is timed:
the bar is correctness under the benchmark's own plumbing (seq accounting on the service
side, transitions that match the core run offline), so it holds on a loaded two-core machine.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from benchmarks.fleet_load import LoadSpec, format_report, run_load, simulated_streams
from lessmap.core import Partitioner, PartitionParams
from lessmap_schemas.partition import PARTITIONS

pytestmark = pytest.mark.timeout(120)

# Robots walk 2 m/s with short pauses so that, in 50 frames, several of them cross a door
# (seed 2: all five do, offline). With --max-batch-frames 1 the service decides at every
# frame, so its transitions are exactly the core's on the same streams: the paper's
# partitioner on both sides (`method`), as `offline_transitions` runs it.
SPEC = LoadSpec(
    robots=5,
    rate_hz=10.0,
    features=10,
    duration_s=5.0,
    seed=2,
    generators=2,
    speed_mps=2.0,
    dwell_s=(0.0, 1.0),
    max_batch_frames=1,
    baseline_robots=1,
    method="paper",
)


def offline_transitions(spec: LoadSpec, spacing: float) -> dict[str, list[int]]:
    """Seqs of the transitions the core finds, per robot, on the benchmark's streams."""
    found: dict[str, list[int]] = {}
    for generator in range(spec.generators):
        indices = spec.robots_of(generator)
        for index, stream in zip(indices, simulated_streams(spec, generator, spacing), strict=True):
            partitioner = Partitioner(PartitionParams.from_profile("laser"))
            seqs = [
                seq
                for seq, features in enumerate(stream)
                if partitioner.observe(seq, seq / spec.rate_hz, features) is not None
            ]
            if seqs:
                found[f"robot{index:04d}"] = seqs
    return found


@pytest.mark.parametrize(
    ("linger_ms", "instances"), [(None, 1), (5.0, 2)], ids=["no-linger", "linger-5ms-2-instances"]
)
def test_small_fleet_loses_nothing_and_every_crossing_robot_gets_its_transitions(
    linger_ms: float | None, instances: int
) -> None:
    # With lingering, the shard waits for more frames after each wake-up: a different
    # batching path that must lose nothing and, deciding per frame, find the same transitions.
    # The same run splits the fleet over two instances (no extra run: the test stays short).
    spec = dataclasses.replace(SPEC, batch_linger_ms=linger_ms, instances=instances)
    report = run_load(spec)
    summary = format_report(report)

    assert report.drained, summary
    assert report.sessions_reported == spec.robots, summary
    assert report.offered == spec.robots * spec.frames_per_robot, summary
    assert report.lost == 0, summary
    assert (report.missing, report.duplicate, report.rejected) == (0, 0, 0), summary
    assert report.applied_by_robot == report.offered_by_robot, summary

    expected = offline_transitions(spec, report.landmark_spacing_m)
    assert expected, "the seed should make robots cross rooms within the run"
    assert report.transitions_by_robot == expected, summary
    assert report.transitions_service == report.transitions_received, summary
    assert len(report.e2e_s) == report.transitions_received
    assert all(latency >= 0 for latency in report.e2e_s)
    assert not math.isnan(report.baseline_observe_us)

    if instances > 1:
        # Each instance took exactly its robots' frames and SessionEnds; with the default
        # subscription to every partition it saw the other instance's ones too and left them.
        figures = report.instance_figures
        assert len(figures) == instances, summary
        assert sum(f.partitions_at_start for f in figures) == PARTITIONS, summary
        everything = sum(f.frames_offered + f.robots for f in figures)
        for f in figures:
            assert f.received == f.frames_offered + f.robots, summary
            assert f.applied == f.frames_offered, summary
            assert f.foreign == everything - f.received, summary
        assert sum(f.frames_offered for f in figures) == report.offered, summary

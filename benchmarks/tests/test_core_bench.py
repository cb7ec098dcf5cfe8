"""Smoke test of the core benchmark: tiny sizes, the table, and decisions equal to exact LAPACK.

No timing is asserted: the figures depend on the machine.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from benchmarks import core_bench, core_streams
from lessmap.core.paper import covgraph

if TYPE_CHECKING:
    from benchmarks.core_streams import Stream


def test_the_table_is_printed_at_tiny_sizes(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--sizes", "50,450", "--frames", "12", "--no-memory", "--worst", "2"]
    argv += ["--visual-frames", "20", "--visual-alive", "120"]
    assert core_bench.main(argv) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert core_bench.HEADER in lines
    rows = [line for line in lines if line.startswith(("room chain n=", "visual "))]
    assert [row.split()[2] for row in rows[:2]] == ["n=50", "n=450"]
    assert len(rows) == 3
    for row in rows:
        assert "nan" not in row
    assert "MRPT:" in out
    worst = [line for line in lines if line.startswith("  worst of ")]
    assert [line.split(":")[0] for line in worst] == [
        "  worst of n=50",
        "  worst of n=450",
        "  worst of visual",
    ]
    frames = [int(row.split()[3]) for row in rows[:2]] + [int(rows[2].split()[2])]
    for line, measured in zip(worst, frames, strict=True):
        listed, tally = line.split("; decisions: ")
        assert listed.count(" ms (") == 2
        kinds = dict(entry.split() for entry in tally.split(", "))
        assert set(kinds) <= {"none", "proven", "solve", "transition"}
        assert sum(int(count) for count in kinds.values()) == measured
        assert int(kinds["transition"]) >= 1  # each stream crosses a door


@pytest.mark.parametrize(
    "stream",
    [
        core_streams.room_chain(50, frames=20),
        core_streams.room_chain(200, frames=20),  # dense counts, the λ2 floor carried
        core_streams.room_chain(450, frames=12),  # above 400 nodes: CSR counts and ARPACK
        core_streams.visual(frames_per_room=25, alive=120, pool=300, warmup=5),
    ],
    ids=["room chain 50", "room chain 200", "room chain 450", "small visual"],
)
def test_decisions_on_the_benchmark_streams_equal_the_exact_dense_solver(stream: Stream) -> None:
    params = core_bench.params_of(stream)
    fast = core_bench.decisions(stream, params, exact=False)
    exact = core_bench.decisions(stream, params, exact=True)
    assert fast == exact
    assert any(len(decision) > 4 for decision in fast)  # at least one transition compared


def test_decisions_with_the_dense_store_above_dense_max_nodes_equal_the_exact_dense_solver() -> (
    None
):
    # 120 of 300 landmarks a frame: most pairs are edges, so above 100 nodes the graph is
    # held in the dense store and handed to ARPACK as CSR (71 of the 75 decisions).
    stream = core_streams.visual(frames_per_room=25, alive=120, pool=300, warmup=5)
    params = core_bench.params_of(stream, dense_max_nodes=100)
    fast = core_bench.decisions(stream, params, exact=False)
    assert fast == core_bench.decisions(stream, params, exact=True)
    assert any(len(decision) > 4 for decision in fast)


def test_the_store_comparison_runs_both_stores_to_the_same_decisions() -> None:
    stream = core_streams.visual(frames_per_room=15, alive=120, pool=300, warmup=5)
    line = core_bench.store_ab(stream, core_bench.params_of(stream, dense_max_nodes=100))
    assert "dense store: median" in line
    assert "sparse store: median" in line
    assert line.endswith("same decisions: True")
    assert covgraph.DENSE_STORE_MAX_NODES == 4096  # restored

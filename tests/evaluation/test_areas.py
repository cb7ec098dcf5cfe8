"""Both segmentation methods offline: revisit scores, the benchmark's pieces, the CLI."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from lessmap.cli.app import main
from lessmap.core.areas.tracker import AreaParams
from lessmap.evaluation.methods import (
    AreaEvent,
    RevisitScore,
    area_of_frames,
    revisit_score,
    run_method,
)
from lessmap.evaluation.studies.areabench import Tally, dlr_loss, revisits_met, rows
from lessmap.files.frames import FrameRow
from lessmap.sim.simulator import TruthRow, simulate
from tests.core.helpers import room_walk

if TYPE_CHECKING:
    from lessmap.sim.simulator import SimRun

DLR = Path(__file__).resolve().parents[2] / ".." / "shared" / "datasets" / "dlr.frames.jsonl"


def event(seq: int, area: int, boundary: int | None = None) -> AreaEvent:
    b = seq if boundary is None else boundary
    return AreaEvent("r", seq, b, float(seq), area, 0, False, 5, "SPECTRAL")


def truth(rooms: list[int]) -> list[TruthRow]:
    return [
        TruthRow("r", seq, float(seq), room, 0.0, 0.0, None, 0.0) for seq, room in enumerate(rooms)
    ]


def test_frames_take_the_area_of_the_last_boundary() -> None:
    events = [event(5, 1, boundary=3), event(9, 0, boundary=8)]
    assert area_of_frames(range(10), events) == [0, 0, 0, 1, 1, 1, 1, 1, 0, 0]


def test_revisit_score_by_hand() -> None:
    # rooms A A B B A A C C B: visits A, B, A, C, B (two revisits)
    rooms = [0, 0, 1, 1, 0, 0, 2, 2, 1]
    # areas: 0 0 1 1 0 0 2 2 0 -> A's revisit named, B's revisit given A's area (false)
    events = [event(2, 1), event(4, 0), event(6, 2), event(8, 0)]
    score = revisit_score(truth(rooms), {"r": events})
    assert (score.visits, score.revisits, score.recognised, score.false) == (5, 2, 1, 1)
    assert score.recognised_share == 0.5
    assert score.false_share == 0.2


def test_the_paper_never_names_a_revisit(sim_run: SimRun) -> None:
    frames = rows(sim_run.frames)
    paper = run_method(frames, "paper")
    assert all(not e.revisit for found in paper.values() for e in found)
    areas = run_method(frames, "areas")
    assert set(paper) == set(areas) == {"robot0", "robot1"}
    assert all(e.closed_features >= 5 for found in areas.values() for e in found)
    # every paper area is new, so only a room's first visit can be named right
    assert revisit_score(sim_run.truth, paper).recognised <= 1


def test_areas_name_the_rooms_a_simulated_robot_returns_to() -> None:
    run = simulate(0, rooms=4, robots=1, frames_per_robot=400)
    found = run_method(rows(run.frames), "areas")
    score = revisit_score(run.truth, found)
    assert score.revisits >= 5
    assert score.recognised_share is not None
    assert score.recognised_share >= 0.8
    assert score.false_share is not None
    assert score.false_share <= 0.1
    events = [e for mine in found.values() for e in mine]
    recognised = [e for e in events if e.reason == "RECOGNISED"]
    assert recognised  # rule 5 found some of them, and says so
    assert all(e.revisit for e in recognised)
    assert {e.reason for e in events} <= {"SPECTRAL", "DISCONNECTED", "RECOGNISED"}


def test_the_revisit_target_counts_no_false_name_as_met() -> None:
    assert revisits_met(RevisitScore(visits=10, revisits=5, recognised=5, false=0))
    assert not revisits_met(RevisitScore(visits=10, revisits=5, recognised=4, false=0))
    assert not revisits_met(RevisitScore(visits=100, revisits=50, recognised=50, false=3))
    assert not revisits_met(RevisitScore(visits=0, revisits=0, recognised=0, false=0))


def test_unknown_method_is_named() -> None:
    with pytest.raises(ValueError, match="unknown method 'x'"):
        run_method([], "x")


def test_tally_counts_per_robot_and_ten_minutes() -> None:
    frames = [FrameRow(r, s, 60.0 * s, (1,), None) for r in ("a", "b") for s in range(11)]
    tally = Tally()
    tally.add({"a": [event(3, 1)], "b": []}, frames)
    assert (tally.robots, tally.minutes, tally.transitions, tally.tiny) == (2, 20.0, 1, 0)
    assert tally.per_robot_10min == 0.5


@pytest.mark.skipif(not DLR.is_file(), reason="../shared/datasets/dlr.frames.jsonl not present")
def test_dlr_loss_compares_at_equal_count() -> None:
    found = {row.name: row for row in dlr_loss(DLR)}
    assert set(found) == {"paper", "areas", "areas, revisits merged"}
    assert found["paper"].submaps == 116  # the paper's decisions, unchanged
    assert found["areas, revisits merged"].submaps < found["areas"].submaps


def test_segment_method_areas_prints_areas(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    walk = room_walk(2, rooms=3, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    lines = [
        json.dumps(
            {
                "robot": "r1",
                "seq": seq,
                "stamp": seq / 10,
                "features": [f + 10**6 for f in frame],
                "pose": None,
            }
        )
        for seq, frame in enumerate(walk.frames)
    ]
    path = tmp_path / "walk.frames.jsonl"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert main(["segment", "--method", "areas", str(path)]) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    *changes, summary = records
    assert [c["area"] for c in changes] == [1, 2, 1, 0]
    assert [c["revisit_of"] for c in changes] == [None, None, 1, 0]
    assert {c["rule"] for c in changes} <= {"split", "recognised"}
    assert changes[0]["rule"] == "split"  # a first visit is always the proposer's
    for change in changes:  # a recognised change ran no Eq. 4 test, and says so
        assert (change["reason"] == "RECOGNISED") == (change["rule"] == "recognised")
    assert summary["method"] == "areas"
    assert summary["areas_per_robot"] == {"r1": 3}
    assert summary["params"]["ncut_min"] == 0.44
    assert summary["params"]["merge_overlap"] == AreaParams().merge_overlap
    assert summary["params"]["weak_frames"] == AreaParams().weak_frames  # every setting listed
    assert main(["segment", str(path), "--method", "paper", "--summary-only"]) == 0
    paper = json.loads(capsys.readouterr().out)
    assert "method" not in paper
    assert paper["params"]["ncut_min"] == 0.25

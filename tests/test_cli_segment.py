"""``lessmap segment``: offline segmentation of a frames file, in-process and as a script."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.cli.app import main
from lessmap.config.settings import LimitSettings
from lessmap_schemas.limits import DEFAULT_LIMITS
from tests.core.helpers import TWO_ROOM_DOOR, room_walk, two_room_frames

if TYPE_CHECKING:
    from collections.abc import Sequence

ROOT = Path(__file__).resolve().parents[1]
DATASETS = ROOT / ".." / "shared" / "datasets"
DLR = DATASETS / "dlr.frames.jsonl"


def frame_line(robot: str, seq: int, features: Sequence[int]) -> str:
    row = {"robot": robot, "seq": seq, "stamp": seq / 10, "features": list(features)}
    return json.dumps({**row, "pose": None})


def write_frames(path: Path, robots: Sequence[str] = ("r1",)) -> Path:
    """The two-room stream for each robot, robots interleaved frame by frame."""
    lines = [
        frame_line(robot, seq, frame)
        for seq, frame in enumerate(two_room_frames())
        for robot in robots
    ]
    path.write_text("\n".join(lines) + "\n\n", encoding="utf-8")  # a trailing blank line
    return path


def run(argv: Sequence[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[Any], str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, [json.loads(line) for line in captured.out.splitlines()], captured.err


def test_two_rooms_print_one_transition_and_a_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_frames(tmp_path / "rooms.frames.jsonl")
    code, records, err = run(["segment", str(path), "--method", "paper"], capsys)
    assert code == 0
    assert err == ""
    [transition, summary] = records

    assert transition["robot"] == "r1"
    assert transition["reason"] == "SPECTRAL"
    assert transition["boundary_seq"] <= transition["seq"]
    assert abs(transition["boundary_seq"] - TWO_ROOM_DOOR) <= 2
    assert transition["stamp_s"] == pytest.approx(transition["seq"] / 10)
    assert 0.0 <= transition["lambda2"] <= 0.2
    assert transition["lambda2"] <= transition["ncut"] <= 0.25
    assert transition["closed"]["features"] == list(range(10))
    assert transition["closed"]["id"] == 0
    assert transition["closed"]["first_seq"] == 0
    assert transition["closed"]["frame_count"] == transition["boundary_seq"]
    assert transition["opened"] == {
        "id": 1,
        "first_seq": transition["boundary_seq"],
        "features": list(range(10, 20)),
    }
    assert set(transition["boundary_features"]) <= set(range(5, 20))

    assert summary["summary"] is True
    assert summary["file"] == path.name
    assert (summary["frames"], summary["robots"], summary["transitions"]) == (62, 1, 1)
    assert summary["transitions_per_robot"] == {"r1": 1}
    assert summary["submaps"] == 2
    assert summary["params"] == {"ncut_min": 0.25, "lambda2_min": 0.2, "seed_mode": "seed"}


def test_the_default_method_is_areas(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_frames(tmp_path / "rooms.frames.jsonl")

    def records(*argv: str) -> list[Any]:
        code, found, err = run(["segment", str(path), *argv], capsys)
        assert (code, err) == (0, "")
        for record in found:  # timings differ from run to run
            record.pop("elapsed_s", None)
            record.pop("ms_per_frame", None)
        return found

    default = records()
    assert default == records("--method", "areas")
    assert default != records("--method", "paper")
    [transition, summary] = default
    assert (summary["method"], summary["areas_per_robot"]) == ("areas", {"r1": 2})
    assert summary["params"]["min_area_features"] == 5  # the area tracker's parameters
    assert (transition["area"], transition["left_area"], transition["rule"]) == (1, 0, "split")
    # The area graph needs the areas method: the default has it.
    assert main(["segment", str(path), "--area-graph", str(tmp_path / "g.json")]) == 0
    assert (tmp_path / "g.json").is_file()


def test_robots_are_segmented_independently_and_can_be_selected(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_frames(tmp_path / "fleet.frames.jsonl", robots=("a", "b"))
    code, records, _ = run(["segment", str(path)], capsys)
    assert code == 0
    *transitions, summary = records
    assert sorted(t["robot"] for t in transitions) == ["a", "b"]
    first, second = transitions
    assert {k: v for k, v in first.items() if k != "robot"} == {
        k: v for k, v in second.items() if k != "robot"
    }
    assert (summary["frames"], summary["robots"], summary["submaps"]) == (124, 2, 4)

    code, records, _ = run(["segment", str(path), "--robot", "b", "--summary-only"], capsys)
    assert code == 0
    [summary] = records
    assert summary["transitions_per_robot"] == {"b": 1}
    assert summary["frames"] == 62


def test_profile_and_overrides_reach_the_partitioner(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_frames(tmp_path / "rooms.frames.jsonl")
    argv = ["segment", str(path), "--method", "paper", "--profile", "monocular"]
    code, records, _ = run([*argv, "--seed-mode", "fresh"], capsys)
    assert code == 0
    assert records[-1]["params"] == {"ncut_min": 0.1, "lambda2_min": 0.1, "seed_mode": "fresh"}
    # Ncut 0 is never reached by a connected split: no transition at all.
    code, records, _ = run(["segment", str(path), "--method", "paper", "--ncut-min", "0"], capsys)
    assert code == 0
    assert records[-1]["transitions"] == 0


GOOD = [frame_line("r1", 0, [1, 2]), frame_line("r1", 1, [2, 3])]
BIG_SEQ = 10**23

#: Malformed third lines: (bytes of the line, what the one-line message must say).
MALFORMED: dict[str, tuple[bytes, str]] = {
    "not utf-8": (b'{"robot": "r\xff1", "seq": 2, "stamp": 0.2, "features": []}', "not UTF-8"),
    "not json": (b'{"robot": "r1", "seq": 2,', "not JSON"),
    "not an object": (b"[1, 2, 3]", "expected an object, got list"),
    "missing field": (
        json.dumps({"robot": "r1", "seq": 2, "stamp": 0.2}).encode(),
        "missing field 'features'",
    ),
    "missing fields": (json.dumps({"robot": "r1"}).encode(), "'seq', 'stamp', 'features'"),
    "pose not numeric": (
        json.dumps(
            {"robot": "r1", "seq": 2, "stamp": 0.2, "features": [1], "pose": ["x", 0, 0]}
        ).encode(),
        "pose must be [x, y, theta]",
    ),
    "pose not finite": (
        b'{"robot": "r1", "seq": 2, "stamp": 0.2, "features": [1], "pose": [NaN, 0, 0]}',
        "pose must be [x, y, theta]",
    ),
    "seq 10^23": (
        frame_line("r1", BIG_SEQ, [1]).encode(),
        f"seq {BIG_SEQ} is above the wire limit",
    ),
    "seq above max_seq": (
        frame_line("r1", DEFAULT_LIMITS.max_seq + 1, [1]).encode(),
        f"is above the wire limit {DEFAULT_LIMITS.max_seq}",
    ),
    "negative seq": (
        json.dumps({"robot": "r1", "seq": -2, "stamp": 0.2, "features": []}).encode(),
        "seq must be an integer >= 0, got -2",
    ),
    "10000 features": (
        frame_line("r1", 2, range(10_000)).encode(),
        "10000 features, more than the limit of 4096 per frame",
    ),
    "negative feature id": (
        frame_line("r1", 2, [1, -3]).encode(),
        "feature 1 must be an integer in 0..",
    ),
    "feature not int": (
        json.dumps({"robot": "r1", "seq": 2, "stamp": 0.2, "features": [1.5]}).encode(),
        "feature 0 must be an integer",
    ),
    "feature id too large": (
        frame_line("r1", 2, [DEFAULT_LIMITS.max_feature_id + 1]).encode(),
        "feature 0 must be an integer",
    ),
    "stamp not a number": (
        json.dumps({"robot": "r1", "seq": 2, "stamp": "noon", "features": []}).encode(),
        "stamp must be a finite number",
    ),
    "duplicate seq": (frame_line("r1", 1, [1, 2]).encode(), "robot r1: frame seq 1 is not after"),
}


def write_broken(folder: Path, bad: bytes) -> Path:
    path = folder / "broken.frames.jsonl"
    lines = [line.encode() for line in GOOD] + [bad, frame_line("r1", 3, [3]).encode()]
    path.write_bytes(b"\n".join(lines) + b"\n")
    return path


def assert_one_error_line(err: str, path: Path, message: str) -> None:
    assert err.endswith("\n")
    assert err.count("\n") == 1, err
    assert err.startswith(f"lessmap segment: {path}:3: "), err
    assert message in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("case", MALFORMED)
def test_malformed_line_is_one_error_line_naming_file_and_line(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad, message = MALFORMED[case]
    path = write_broken(tmp_path, bad)
    code = main(["segment", str(path)])
    captured = capsys.readouterr()
    assert code == 1
    assert_one_error_line(captured.err, path, message)


@pytest.mark.parametrize("case", MALFORMED)
def test_malformed_line_as_a_script(case: str, tmp_path: Path) -> None:
    bad, message = MALFORMED[case]
    path = write_broken(tmp_path, bad)
    result = subprocess.run(
        [sys.executable, "-m", "lessmap", "segment", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 1, result.stderr
    assert_one_error_line(result.stderr, path, message)


def test_the_feature_limit_is_the_services_and_a_flag_changes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert LimitSettings().max_features_per_frame == 4096  # what serve enforces by default
    path = tmp_path / "wide.frames.jsonl"
    path.write_text(
        "\n".join(frame_line("r1", seq, range(seq, seq + 4097)) for seq in range(3)) + "\n",
        encoding="utf-8",
    )
    assert main(["segment", str(path), "--summary-only"]) == 1
    assert "4097 features, more than the limit of 4096" in capsys.readouterr().err

    assert main(["segment", str(path), "--summary-only", "--max-features-per-frame", "5000"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 3

    assert main(["segment", str(path), "--max-features-per-frame", "2"]) == 1
    assert "features, more than the limit of 2 " in capsys.readouterr().err

    assert main(["segment", str(path), "--max-features-per-frame", "0"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "--max-features-per-frame" in err


def test_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    # `lessmap segment FILE | head -1`: far more output than a pipe holds, read one line,
    # close the pipe. The writer must stop with code 0 and say nothing.
    path = write_frames(tmp_path / "many.frames.jsonl", robots=[f"r{i}" for i in range(300)])
    with subprocess.Popen(
        [sys.executable, "-m", "lessmap", "segment", str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    ) as process:
        assert process.stdout is not None
        assert process.stderr is not None
        first = process.stdout.readline()
        process.stdout.close()
        err = process.stderr.read()
        code = process.wait(timeout=120)
    assert json.loads(first)["robot"] == "r0"
    assert err == b""
    assert code == 0


@pytest.mark.parametrize(
    ("argv", "message", "code"),
    [
        (["segment", "nowhere.frames.jsonl"], "nowhere.frames.jsonl", 1),
        # A flag's value out of range is a wrong command line: exit 2, as argparse's own.
        (["segment", "FRAMES", "--min-cluster-size", "0"], "min_cluster_size", 2),
        (["segment", "FRAMES", "--lambda2-min", "-1"], "lambda2_min", 2),
    ],
    ids=["missing file", "bad guard", "bad threshold"],
)
def test_user_errors_exit_1_or_2_with_one_line(
    argv: list[str], message: str, code: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = str(write_frames(tmp_path / "rooms.frames.jsonl"))
    argv = [
        frames if a == "FRAMES" else str(tmp_path / a) if a.endswith(".jsonl") else a for a in argv
    ]
    assert main(argv) == code
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert message in err


@pytest.mark.skipif(not DLR.is_file(), reason=f"data set not present: {DLR}")
def test_console_script_on_the_dlr_data_set() -> None:
    result = subprocess.run(
        # The paper's partitioner: its thresholds and submap chain are what is checked.
        [
            sys.executable,
            "-m",
            "lessmap",
            "segment",
            "--method",
            "paper",
            str(DLR.relative_to(ROOT)),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    *transitions, summary = [json.loads(line) for line in result.stdout.splitlines()]

    assert summary["summary"] is True
    assert summary["frames"] == 3297
    assert summary["transitions"] == len(transitions)
    assert 5 <= len(transitions) <= 200
    assert summary["submaps"] == len(transitions) + 1
    boundary = 0  # submaps chain up: each closed submap starts at the previous boundary
    for index, transition in enumerate(transitions):
        closed = transition["closed"]
        assert closed["first_seq"] == boundary
        assert boundary < transition["boundary_seq"] <= transition["seq"]
        boundary = transition["boundary_seq"]
        assert closed["id"] == index
        assert len(closed["features"]) >= 1
        assert closed["frame_count"] >= 1
        assert closed["first_seq"] <= closed["last_seq"] < transition["boundary_seq"]
        assert transition["opened"]["features"]
        if transition["reason"] == "SPECTRAL":
            assert transition["ncut"] <= 0.25
            assert transition["lambda2"] <= 0.2
        else:
            assert transition["reason"] == "DISCONNECTED"
            assert transition["ncut"] is None
            assert transition["lambda2"] is None


def walk_file(path: Path, robots: Sequence[str], *, offset: int = 10**6) -> Path:
    """A there-and-back walk through three rooms for each robot (feature ids + ``offset``)."""
    walk = room_walk(2, rooms=3, back=True, stay=(20, 30), door_frames=2, door_share=0.2)
    lines = [
        frame_line(robot, seq, [f + offset for f in frame])
        for seq, frame in enumerate(walk.frames)
        for robot in robots
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize(("shared", "fleet_areas"), [(False, 6), (True, 3)])
def test_segment_writes_the_area_graphs(
    shared: bool, fleet_areas: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = walk_file(tmp_path / "walk.frames.jsonl", ["r1", "r2"])
    out = tmp_path / "graph.json"
    argv = ["segment", "--method", "areas", "--area-graph", str(out), str(frames)]
    code, records, err = run([*argv, *(["--shared-features"] if shared else [])], capsys)
    assert (code, err) == (0, "")
    summary = records[-1]
    assert summary["fleet_areas"] == fleet_areas
    assert summary["area_graph"] == str(out)
    document = json.loads(out.read_text(encoding="utf-8"))
    assert document["format"] == "lessmap.area_graph/1"
    assert document["source"] == "walk.frames.jsonl"
    assert document["fleet_params"]["shared_features"] is shared
    for robot in ("r1", "r2"):  # route 0 1 2 1 0: a path of three areas, crossed both ways
        graph = document["robots"][robot]
        assert [n["area"] for n in graph["nodes"]] == [0, 1, 2]
        assert [n["visits"] for n in graph["nodes"]] == [2, 2, 1]
        assert sum(n["frames"] for n in graph["nodes"]) == summary["frames"] // 2
        assert [(e["a"], e["b"], e["a_to_b"], e["b_to_a"]) for e in graph["edges"]] == [
            (0, 1, 1, 1),
            (1, 2, 1, 1),
        ]
    fleet = document["fleet"]
    assert len(fleet["nodes"]) == fleet_areas
    if shared:  # the robots walked the same rooms with the same landmark ids
        assert [n["members"] for n in fleet["nodes"]] == [[["r1", a], ["r2", a]] for a in range(3)]
        assert [(e["a"], e["b"], e["a_to_b"] + e["b_to_a"]) for e in fleet["edges"]] == [
            (0, 1, 4),
            (1, 2, 4),
        ]
        assert all(e["robots"] == ["r1", "r2"] for e in fleet["edges"])


def test_robots_with_their_own_feature_ids_stay_apart(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = walk_file(tmp_path / "a.frames.jsonl", ["r1"])
    other = walk_file(tmp_path / "b.frames.jsonl", ["r2"], offset=10**7)  # ids no other robot has
    frames.write_text(frames.read_text() + other.read_text(), encoding="utf-8")
    out = tmp_path / "graph.json"
    argv = ["segment", "--method", "areas", "--area-graph", str(out), "--shared-features"]
    code, records, _ = run([*argv, str(frames)], capsys)
    assert code == 0
    assert records[-1]["fleet_areas"] == 6


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--method", "paper", "--area-graph", "OUT"], "--area-graph needs --method areas"),
        (["--method", "areas", "--shared-features"], "--shared-features needs --area-graph"),
        (["--method", "areas", "--area-graph", "nowhere/OUT"], "nowhere"),
    ],
    ids=["paper method", "shared without graph", "unwritable"],
)
def test_area_graph_misuse_is_one_line(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = str(write_frames(tmp_path / "rooms.frames.jsonl"))
    argv = [str(tmp_path / a) if a.endswith("OUT") else a for a in argv]
    assert main(["segment", frames, *argv]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert message in err


def test_empty_frames_omitted_reads_the_stamp_gaps(capsys: pytest.CaptureFixture[str]) -> None:
    # MRCLAM's frames are sightings: robot 3's blind turns between two walls show only as
    # stamp gaps, which are read as blindness only when the file is declared so.
    path = DATASETS / "mrclam6.frames.jsonl"
    if not path.exists():
        pytest.skip("data set mrclam6 not found under ../shared/datasets")
    argv = ["segment", "--method", "areas", "--robot", "3", str(path)]
    # Sightings are sparse (under 2 features a frame): said once on stderr, not an error.
    sparse = f"lessmap segment: warning: {path}: its "
    code, records, err = run(argv, capsys)
    assert code == 0
    assert err.startswith(sparse), err
    assert err.count("\n") == 1
    assert records[-1]["transitions"] >= 3
    assert records[-1]["params"]["period_steps"] == 0
    code, records, err = run([*argv, "--empty-frames-omitted"], capsys)
    assert code == 0
    assert err.startswith(sparse), err
    assert records[-1]["transitions"] == 0
    assert records[-1]["params"]["period_steps"] > 0
    assert len(records) == 1  # the summary alone


def camera_frames_file(path: Path) -> Path:
    """Two rooms of 300 features a frame (a camera's wall texture): over a small cap."""
    frames = [[f * 32 + k for f in frame for k in range(20)] for frame in two_room_frames()]
    path.write_text("\n".join(frame_line("cam", s, f) for s, f in enumerate(frames)) + "\n")
    return path


def without_timing(records: list[Any]) -> list[Any]:
    return [{k: v for k, v in r.items() if k not in ("elapsed_s", "ms_per_frame")} for r in records]


def test_the_cap_samples_the_default_method_and_leaves_the_paper_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = camera_frames_file(tmp_path / "cam.frames.jsonl")
    paper = run(["segment", str(path), "--method", "paper"], capsys)[1]
    capped = run(["segment", str(path), "--method", "paper", "--max-features-kept", "8"], capsys)
    assert without_timing(capped[1]) == without_timing(paper)  # paper: every feature, always
    whole = run(["segment", str(path), "--max-features-kept", "0"], capsys)[1]
    sampled = run(["segment", str(path), "--max-features-kept", "64"], capsys)[1]
    assert whole[-1]["params"]["max_features_kept"] == 0
    assert sampled[-1]["params"]["max_features_kept"] == 64
    # the door found either way; the submaps list the kept ids only, a subset of the whole
    assert [r["boundary_seq"] for r in sampled[:-1]] == [r["boundary_seq"] for r in whole[:-1]]
    for part in ("closed", "opened"):
        kept, every = set(sampled[0][part]["features"]), set(whole[0][part]["features"])
        assert kept < every
        assert len(kept) < len(every) / 2


def test_spans_in_views_reach_the_areas_method(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = camera_frames_file(tmp_path / "cam.frames.jsonl")
    plain = run(["segment", str(path), "--no-spans-in-views"], capsys)[1]
    views = run(["segment", str(path)], capsys)[1]  # on by default
    assert plain[-1]["params"]["spans_in_views"] is False
    assert views[-1]["params"]["spans_in_views"] is True
    # the door found either way (a two-room walk: its spans decide when, not whether)
    assert len(views) == len(plain) >= 2

"""The frames-file rules of the contract: one checker behind ``segment`` and ``replay``."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import pytest

from lessmap_schemas.errors import FramesFileError
from lessmap_schemas.framesfile import checked_frame, frame_problem, read_lines
from lessmap_schemas.limits import DEFAULT_LIMITS

if TYPE_CHECKING:
    from pathlib import Path

GOOD: dict[str, Any] = {"robot": "r1", "seq": 3, "stamp": 0.5, "features": [1, 2], "pose": None}


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"seq": -1}, "seq must be an integer >= 0"),
        ({"seq": True}, "seq must be an integer >= 0"),
        ({"seq": DEFAULT_LIMITS.max_seq + 1}, "is above the wire limit"),
        ({"stamp": "noon"}, "stamp must be a finite number"),
        ({"stamp": float("nan")}, "stamp must be a finite number"),
        ({"features": "1,2"}, "features must be a list of integers"),
        ({"features": [1, -2]}, "feature 1 must be an integer in 0.."),
        ({"features": [0] * (DEFAULT_LIMITS.max_features_per_frame + 1)}, "more than the limit"),
        ({"pose": [1.0, "x", 0.0]}, "pose must be [x, y, theta]"),
        ({"robot": ""}, "robot must be a non-empty string"),
    ],
)
def test_every_rule_names_what_is_wrong(change: dict[str, Any], problem: str) -> None:
    found = frame_problem({**GOOD, **change}, DEFAULT_LIMITS)
    assert found is not None
    assert problem in found


def test_a_good_frame_passes_and_missing_fields_are_named() -> None:
    assert frame_problem(GOOD, DEFAULT_LIMITS) is None
    assert frame_problem({"robot": "r"}, DEFAULT_LIMITS) == (
        "missing field 'seq', 'stamp', 'features'"
    )
    with pytest.raises(FramesFileError, match=r"^f:7: seq must be"):
        checked_frame({**GOOD, "seq": -1}, "f:7", DEFAULT_LIMITS)


def test_lines_are_read_as_utf8_with_their_place(tmp_path: Path) -> None:
    path = tmp_path / "x.frames.jsonl"
    path.write_bytes(json.dumps(GOOD).encode() + b"\n\n" + b'{"robot": "\xff"}\n')
    lines = read_lines(path)
    assert next(lines)[0] == f"{path}:1"
    with pytest.raises(FramesFileError, match=r":3: not UTF-8 \(byte 0xff at column 12\)"):
        next(lines)

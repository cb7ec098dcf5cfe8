from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from lessmap_schemas import MESSAGE_TYPES, WireError, decode, encode

SCHEMAS = Path(__file__).resolve().parents[2] / "schemas"
VECTORS = SCHEMAS / "vectors"


def load(kind: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((VECTORS / f"{kind}.json").read_text(encoding="utf-8"))
    return data


def cases(group: str) -> list[Any]:
    return [
        pytest.param(kind, case, id=f"{kind}-{case['name']}")
        for kind in MESSAGE_TYPES
        for case in load(kind)[group]
    ]


def test_one_vector_file_per_message_type() -> None:
    # One file per message type, partition.json (section 2a; tests/schemas/test_partition.py)
    # and fleet_areas.json (the SDKs' fleet merge; tests/client/test_fleet_areas.py).
    expected = sorted([*MESSAGE_TYPES, "partition", "fleet_areas"])
    assert sorted(path.stem for path in VECTORS.glob("*.json")) == expected
    for kind in MESSAGE_TYPES:
        data = load(kind)
        assert data["type"] == kind
        assert len(data["valid"]) >= 2
        assert len(data["invalid"]) >= 20


@pytest.mark.parametrize(("kind", "case"), cases("valid"))
def test_valid_vector(kind: str, case: dict[str, Any]) -> None:
    model = MESSAGE_TYPES[kind]
    data = bytes.fromhex(case["hex"])
    message = decode(data, model)
    assert message.model_dump(mode="json") == case["json"]
    # The JSON meaning is itself a valid message, and the same one.
    assert model.model_validate_json(json.dumps(case["json"])) == message
    assert (encode(message) == data) is case["canonical"]
    if case["canonical"]:
        assert encode(message).hex() == case["hex"]


@pytest.mark.parametrize(("kind", "case"), cases("valid"))
def test_valid_vector_meets_its_json_schema(kind: str, case: dict[str, Any]) -> None:
    schema = json.loads((SCHEMAS / "jsonschema" / f"{kind}.json").read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(schema).validate(case["json"])


@pytest.mark.parametrize(("kind", "case"), cases("invalid"))
def test_invalid_vector(kind: str, case: dict[str, Any]) -> None:
    with pytest.raises(WireError) as info:
        decode(bytes.fromhex(case["hex"]), MESSAGE_TYPES[kind])
    assert info.value.code == case["code"], str(info.value)
    assert info.value.limit == case["limit"]


def test_vectors_match_their_generator() -> None:
    result = subprocess.run(
        [sys.executable, str(VECTORS / "generate.py"), "--check"],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr


def test_generator_reports_stale_files(tmp_path: Path) -> None:
    command = [sys.executable, str(VECTORS / "generate.py"), "--out", str(tmp_path)]
    subprocess.run(command, check=True, timeout=60)
    (tmp_path / "Health.json").write_text("{}\n", encoding="utf-8")
    result = subprocess.run(
        [*command, "--check"], capture_output=True, text=True, check=False, timeout=60
    )
    assert result.returncode == 1
    assert "Health.json" in result.stderr

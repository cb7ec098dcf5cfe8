from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jsonschema
import msgpack
import pytest

from lessmap_schemas import MESSAGE_TYPES, Message, encode
from lessmap_schemas.export import DEFAULT_OUT, main
from tests.schemas.samples import samples

CHECKED_IN = Path(__file__).resolve().parents[2] / "schemas" / "jsonschema"


def test_default_out_is_the_checked_in_folder() -> None:
    assert DEFAULT_OUT == CHECKED_IN


def test_checked_in_schemas_are_current(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--check"]) == 0
    assert "up to date" in capsys.readouterr().out


def test_module_entry_point_checks() -> None:
    env = {**os.environ, "PYTHONPATH": str(CHECKED_IN.parent)}
    result = subprocess.run(
        [sys.executable, "-m", "lessmap_schemas.export", "--check"],
        capture_output=True,
        text=True,
        env=env,
        check=False,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr


def test_written_files_are_deterministic(tmp_path: Path) -> None:
    assert main(["--out", str(tmp_path)]) == 0
    first = {path.name: path.read_bytes() for path in tmp_path.iterdir()}
    assert sorted(first) == sorted(f"{name}.json" for name in MESSAGE_TYPES)
    assert main(["--out", str(tmp_path)]) == 0
    assert {path.name: path.read_bytes() for path in tmp_path.iterdir()} == first
    for name, text in first.items():
        assert text.endswith(b"}\n")
        schema = json.loads(text)
        assert schema["$id"] == f"https://lessmap.dev/schemas/v4/{name}"
        assert schema["title"] == name.removesuffix(".json")
        assert schema["required"][:2] == ["type", "v"]
        assert text == (json.dumps(schema, indent=2, sort_keys=True) + "\n").encode()


@pytest.mark.parametrize("damage", ["edit", "delete", "extra"])
def test_check_names_stale_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    assert main(["--out", str(tmp_path)]) == 0
    target = tmp_path / "Frame.json"
    if damage == "edit":
        target.write_text(target.read_text().replace("Frame", "Frames", 1))
    elif damage == "delete":
        target.unlink()
    else:
        target = tmp_path / "Obsolete.json"
        target.write_text("{}\n")
    capsys.readouterr()
    assert main(["--check", "--out", str(tmp_path)]) == 1
    assert target.name in capsys.readouterr().err


def test_check_explains_a_missing_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--check", "--out", str(tmp_path / "absent")]) == 1
    assert "no schema folder" in capsys.readouterr().err


@pytest.mark.parametrize("message", samples(), ids=lambda m: type(m).__name__)
def test_schemas_accept_every_sample(message: Message) -> None:
    name = type(message).__name__
    schema = json.loads((CHECKED_IN / f"{name}.json").read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(schema).validate(msgpack.unpackb(encode(message)))


@pytest.mark.parametrize(
    ("field", "value"),
    [("session", "a*b"), ("session", "x" * 65), ("seq", -1), ("seq", 2**53), ("features", [-1])],
)
def test_schemas_reject_what_the_models_reject(field: str, value: object) -> None:
    schema = json.loads((CHECKED_IN / "Frame.json").read_text(encoding="utf-8"))
    frame = {"type": "Frame", "v": 4, "session": "s", "seq": 1, "stamp_s": 0.0, "features": []}
    jsonschema.Draft202012Validator(schema).validate(frame)  # the baseline is valid
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator(schema).validate({**frame, "v": 1})  # superseded
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator(schema).validate({**frame, field: value})
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator(schema).validate({**frame, "extra": 1})
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator(schema).validate({k: frame[k] for k in frame if k != "v"})


def test_installed_package_refuses_to_guess_the_folder(tmp_path: Path) -> None:
    # Installed, the folder next to the package is site-packages/jsonschema: another library.
    site = tmp_path / "site-packages"
    shutil.copytree(CHECKED_IN.parent / "lessmap_schemas", site / "lessmap_schemas")
    (site / "jsonschema").mkdir()
    (site / "jsonschema" / "__init__.py").write_text("")
    env = {**os.environ, "PYTHONPATH": str(site)}
    for extra in (["--check"], []):
        result = subprocess.run(
            [sys.executable, "-m", "lessmap_schemas.export", *extra],
            capture_output=True,
            text=True,
            env=env,
            check=False,
            timeout=60,
            cwd=tmp_path,
        )
        assert result.returncode == 1
        assert "not in a source checkout" in result.stderr
    assert sorted(path.name for path in (site / "jsonschema").iterdir()) == ["__init__.py"]
    result = subprocess.run(
        [sys.executable, "-m", "lessmap_schemas.export", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        env=env,
        check=False,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert len(list((tmp_path / "out").glob("*.json"))) == len(MESSAGE_TYPES)

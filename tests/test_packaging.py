"""The three distributions, built as a user's pip would build them: what each wheel holds.

Wheels are built from the working tree with the project's own build backend (hatchling,
no network: ``--no-build-isolation``) into ``tmp_path`` and read as zip files.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from email.parser import Parser
from importlib.metadata import requires, version
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DISTRIBUTIONS = {
    "lessmap-schemas": (ROOT / "schemas", "lessmap_schemas"),
    "lessmap-client": (ROOT / "clients" / "python", "lessmap_client"),
    "lessmap": (ROOT, "lessmap"),
}
HEAVY = {"numpy", "scipy", "matplotlib", "prometheus-client", "threadpoolctl"}

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def wheels(tmp_path_factory: pytest.TempPathFactory) -> dict[str, zipfile.ZipFile]:
    out = tmp_path_factory.mktemp("wheels")
    built: dict[str, zipfile.ZipFile] = {}
    for name, (folder, _package) in DISTRIBUTIONS.items():
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "pip",
                "wheel",
                "--no-deps",
                "--no-build-isolation",
                "--quiet",
                "--wheel-dir",
                str(out / name),
                str(folder),
            ],
            capture_output=True,
            text=True,
            timeout=240,
            check=False,
        )
        assert result.returncode == 0, result.stderr
        (wheel,) = (out / name).glob("*.whl")
        built[name] = zipfile.ZipFile(wheel)
    return built


def metadata(wheel: zipfile.ZipFile) -> dict[str, list[str]]:
    (path,) = [n for n in wheel.namelist() if n.endswith(".dist-info/METADATA")]
    message = Parser().parsestr(wheel.read(path).decode())
    return {key: message.get_all(key) or [] for key in ("Name", "Version", "Requires-Dist")}


@pytest.mark.parametrize("name", list(DISTRIBUTIONS))
def test_each_wheel_holds_its_package_typed_and_licensed(
    wheels: dict[str, zipfile.ZipFile], name: str
) -> None:
    names = wheels[name].namelist()
    package = DISTRIBUTIONS[name][1]
    assert f"{package}/py.typed" in names
    assert f"{package}/__init__.py" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), names[-5:]
    others = {p for d, (_, p) in DISTRIBUTIONS.items() if d != name}
    assert not {n.partition("/")[0] for n in names} & others  # every package in its own wheel


def test_the_service_wheel_ships_the_example_floor_plan(
    wheels: dict[str, zipfile.ZipFile],
) -> None:
    names = set(wheels["lessmap"].namelist())
    for file in ("example.png", "example_gt_segmentation.png", "example.yaml"):
        assert f"lessmap/floorplan/data/{file}" in names


def test_one_version_for_all(wheels: dict[str, zipfile.ZipFile]) -> None:
    expected = (ROOT / "VERSION").read_text(encoding="utf-8").strip()
    assert {metadata(w)["Version"][0] for w in wheels.values()} == {expected}
    assert {version(name) for name in DISTRIBUTIONS} == {expected}  # the editable installs


def test_the_schemas_wheel_ships_the_contract_files(wheels: dict[str, zipfile.ZipFile]) -> None:
    names = set(wheels["lessmap-schemas"].namelist())
    for kind in ("vectors", "jsonschema"):
        source = sorted(p.name for p in (ROOT / "schemas" / kind).glob("*.json"))
        assert source, kind
        packaged = sorted(
            n.rpartition("/")[2]
            for n in names
            if n.startswith(f"lessmap_schemas/contract/{kind}/") and n.endswith(".json")
        )
        assert packaged == source


def test_what_a_robot_installs_is_light(wheels: dict[str, zipfile.ZipFile]) -> None:
    for name in ("lessmap-schemas", "lessmap-client"):
        wanted = {
            r.split(";")[0].split("[")[0].split(">")[0].split("<")[0].split("=")[0].strip()
            for r in metadata(wheels[name])["Requires-Dist"]
        }
        assert not wanted & HEAVY, (name, wanted)
    installed = {
        r.split(";")[0].split(">")[0].split("<")[0].strip()
        for r in requires("lessmap-client") or []
    }
    assert not installed & HEAVY


def test_the_service_wheel_carries_no_benchmark_or_test_code(
    wheels: dict[str, zipfile.ZipFile],
) -> None:
    names = wheels["lessmap"].namelist()
    assert not [n for n in names if n.startswith(("tests/", "lessmap/tools/", "docs/"))]
    requirements = metadata(wheels["lessmap"])["Requires-Dist"]
    plain = [r for r in requirements if "extra ==" not in r]
    assert not [r for r in plain if r.startswith("matplotlib")]  # plots are the [eval] extra
    assert any(r.startswith("matplotlib") and "extra == 'eval'" in r for r in requirements)


def test_the_siblings_are_pinned_to_the_same_version(wheels: dict[str, zipfile.ZipFile]) -> None:
    expected = (ROOT / "VERSION").read_text(encoding="utf-8").strip()
    needs = {name: metadata(wheel)["Requires-Dist"] for name, wheel in wheels.items()}
    assert f"lessmap-schemas=={expected}" in needs["lessmap-client"]
    assert {f"lessmap-schemas=={expected}", f"lessmap-client=={expected}"} <= set(needs["lessmap"])
    siblings = [r for rs in needs.values() for r in rs if r.startswith("lessmap")]
    assert all(r.endswith(f"=={expected}") for r in siblings), siblings

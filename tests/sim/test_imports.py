"""``lessmap.sim`` stands alone: the standard library and itself (``command.py`` adds the SDK).

Read from the source with ``ast``, type-checking imports included, so the simulator and
its scorer can be copied or vendored without the service.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

SIM = Path(__file__).resolve().parents[2] / "service" / "lessmap" / "sim"
# The CLI command publishes through the SDK, runs the floor-plan simulator and draws progress.
EXTRA = {"command.py": ("lessmap_client", "lessmap.floorplan", "lessmap.cli.progress")}


def imported(path: Path) -> set[str]:
    """Absolute names of the modules a file's import statements name."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: inside lessmap.sim (or above it, which must fail)
                base = ["lessmap", "sim"][: 3 - node.level]
                found.add(".".join([*base, node.module] if node.module else base))
            else:
                found.add(node.module or "")
    return found - {"__future__"}


def allowed(module: str, extra: tuple[str, ...]) -> bool:
    root = module.partition(".")[0]
    inside = module == "lessmap.sim" or module.startswith("lessmap.sim.")
    granted = any(module == e or module.startswith(e + ".") for e in extra)
    return inside or root in sys.stdlib_module_names or granted


def test_every_module_is_checked() -> None:
    assert {p.name for p in SIM.glob("*.py")} >= {
        "__init__.py",
        "building.py",
        "simulator.py",
        "groundtruth.py",
        "command.py",
    }


@pytest.mark.parametrize("path", sorted(SIM.rglob("*.py")), ids=lambda p: p.name)
def test_sim_imports_the_standard_library_and_itself(path: Path) -> None:
    foreign = {m for m in imported(path) if not allowed(m, EXTRA.get(path.name, ()))}
    assert not foreign, f"{path.name} imports {sorted(foreign)}"


@pytest.mark.parametrize(
    ("source", "bad"),
    [
        ("import numpy", {"numpy"}),
        ("from lessmap.core import Partitioner", {"lessmap.core"}),
        ("from .. import errors", {"lessmap"}),
        ("if True:\n    from lessmap_client import Fleet", {"lessmap_client"}),
        ("import json, math\nfrom . import building\nfrom lessmap.sim.building import Door", set()),
    ],
)
def test_the_check_catches_foreign_imports(tmp_path: Path, source: str, bad: set[str]) -> None:
    path = tmp_path / "probe.py"
    path.write_text(source, encoding="utf-8")
    assert {m for m in imported(path) if not allowed(m, ())} == bad

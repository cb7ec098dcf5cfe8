"""Import rules between the packages, read from the source with ``ast``.

Every ``.py`` file of the three packages is a case, so files added later are covered; a
package folder that does not exist yet gives no cases.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {
    "lessmap_schemas": ROOT / "schemas" / "lessmap_schemas",
    "lessmap": ROOT / "service" / "lessmap",
    "lessmap_client": ROOT / "clients" / "python" / "lessmap_client",
}
PROJECT = frozenset(PACKAGES)


def module_name(path: Path) -> str:
    for package, folder in PACKAGES.items():
        if path.is_relative_to(folder):
            parts = [package, *path.relative_to(folder).with_suffix("").parts]
            return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
    msg = f"{path} is in no package"
    raise ValueError(msg)


def imported_modules(path: Path) -> set[str]:
    """Absolute names of every module an import statement names (type-checking ones too)."""
    source = path.read_text(encoding="utf-8")
    return modules_in(source, module_name(path), is_package=path.name == "__init__.py")


def modules_in(source: str, name: str, *, is_package: bool) -> set[str]:
    tree = ast.parse(source)
    package = name if is_package else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join([*base, node.module] if node.module else base)
            else:
                stem = node.module or ""
            found.add(stem)
            # `from pkg import sub` may import a submodule: count pkg.sub as well.
            found.update(f"{stem}.{alias.name}" for alias in node.names if alias.name != "*")
    return {m for m in found if m.partition(".")[0] != "__future__"}


def roots(modules: set[str]) -> set[str]:
    return {m.partition(".")[0] for m in modules}


def within(module: str, *prefixes: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def project_imports(path: Path) -> set[str]:
    return {m for m in imported_modules(path) if m.partition(".")[0] in PROJECT}


def files(package: str, *sub: str) -> list[Path]:
    folder = PACKAGES[package].joinpath(*sub)
    return sorted(folder.rglob("*.py")) if folder.is_dir() else []


def ids(path: Path) -> str:
    return str(path.relative_to(ROOT))


ALL_FILES = [p for package in PACKAGES for p in files(package)]

CORE_FORBIDDEN = {
    "zenoh",
    "msgpack",
    "pydantic",
    "pydantic_settings",
    "prometheus_client",
    "logging",
    "time",
    "datetime",
    "os",
    "sys",
    "pathlib",
    "shutil",
    "tempfile",
    "socket",
    "select",
    "selectors",
    "threading",
    "multiprocessing",
    "concurrent",
    "asyncio",
    "subprocess",
    "signal",
    "http",
    "urllib",
    "random",
    "lessmap_schemas",
    "lessmap_client",
}


@pytest.mark.parametrize("path", files("lessmap", "core"), ids=ids)
def test_core_stays_sans_io(path: Path) -> None:
    modules = imported_modules(path)
    assert not roots(modules) & CORE_FORBIDDEN
    outside = {m for m in modules if m.partition(".")[0] == "lessmap"}
    assert all(within(m, "lessmap.core") for m in outside), outside


@pytest.mark.parametrize("path", files("lessmap_schemas"), ids=ids)
def test_schemas_depend_on_nothing_heavy(path: Path) -> None:
    forbidden = {"zenoh", "numpy", "scipy", "lessmap", "lessmap_client"}
    assert not roots(imported_modules(path)) & forbidden


@pytest.mark.parametrize("path", files("lessmap_client"), ids=ids)
def test_client_needs_only_the_schemas(path: Path) -> None:
    modules = imported_modules(path)
    assert "scipy" not in roots(modules)
    assert all(within(m, "lessmap_client", "lessmap_schemas") for m in project_imports(path))


@pytest.mark.parametrize("path", ALL_FILES, ids=ids)
def test_only_runtime_and_client_touch_zenoh(path: Path) -> None:
    if "zenoh" in roots(imported_modules(path)):
        name = module_name(path)
        assert within(name, "lessmap.runtime", "lessmap_client"), name


@pytest.mark.parametrize("path", files("lessmap", "evaluation"), ids=ids)
def test_evaluation_builds_on_the_core_only(path: Path) -> None:
    # The offline tools (frames files, errors, offline runs) are core-level too: no I/O
    # beyond reading files, no transport.
    allowed = (
        "lessmap.core",
        "lessmap.evaluation",
        "lessmap.errors",
        "lessmap.frames_file",
        "lessmap.offline",
        "lessmap.partition_options",
    )
    assert all(within(m, *allowed) for m in project_imports(path)), project_imports(path)
    assert "zenoh" not in roots(imported_modules(path))


def test_the_checker_resolves_relative_and_nested_imports() -> None:
    source = (
        "from __future__ import annotations\n"
        "from ..runtime import service\n"
        "from . import spectral\n"
        "if True:\n"
        "    import zenoh.handlers\n"
    )
    found = modules_in(source, "lessmap.core.probe", is_package=False)
    assert {"lessmap.runtime", "lessmap.runtime.service", "lessmap.core.spectral"} <= found
    assert roots(found) == {"lessmap", "zenoh"}
    assert modules_in("from .keys import x", "lessmap_schemas", is_package=True) >= {
        "lessmap_schemas.keys"
    }
    assert module_name(PACKAGES["lessmap"] / "core" / "__init__.py") == "lessmap.core"
    assert module_name(PACKAGES["lessmap"] / "core" / "spectral.py") == "lessmap.core.spectral"


@pytest.mark.skipif(not PACKAGES["lessmap_client"].is_dir(), reason="no client package yet")
def test_importing_the_client_loads_no_scipy() -> None:
    code = "import lessmap_client, sys; assert 'scipy' not in sys.modules, 'scipy loaded'"
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 0, result.stderr

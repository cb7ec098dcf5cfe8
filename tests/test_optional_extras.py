"""A command whose optional extra is missing says which one to install, in one line."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

# Each command, an argument list that gets it past argument parsing, and its extra's module.
CASES = [
    ("ros", ["ros", "--duration", "0"], "rosbags", "ros"),
    ("import", ["import", "run.bag"], "rosbags", "ros"),
    ("view", ["view", "--fleet", "f", "--duration", "0"], "foxglove", "viz"),
    ("record", ["record", "--fleet", "f", "--mcap", "none.mcap"], "foxglove", "viz"),
]


@pytest.mark.parametrize(("command", "argv", "module", "extra"), CASES, ids=[c[0] for c in CASES])
def test_a_missing_extra_is_named(command: str, argv: list[str], module: str, extra: str) -> None:
    # None in sys.modules makes the import fail as if the package were not installed.
    code = (
        "import sys\n"
        f"sys.modules[{module!r}] = None\n"
        "from lessmap.cli.app import main\n"
        f"sys.exit(main({argv!r}))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 1, result.stderr
    # The module named may be a submodule (the first one imported): rosbags.typesys.
    assert re.fullmatch(
        rf"lessmap {command}: this needs {module}(\.\w+)*, from lessmap's optional extra "
        rf"{extra}: pip install '\.\[{extra}\]' in the repository \(README, Install\)",
        result.stderr.strip(),
    ), result.stderr


def readme_test_command() -> str:
    from pathlib import Path

    readme = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    return next(line for line in readme.splitlines() if "scripts/check" in line)


def test_the_extras_stay_optional_and_the_tests_install_them() -> None:
    # The test tools live in requirements-test.txt, out of the published metadata; the
    # README's test command installs every extra the tests exercise.
    import tomllib
    from pathlib import Path

    pyproject = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    extras = pyproject["project"]["optional-dependencies"]
    # The dependencies are the build hook's (hatch_build.py pins the siblings to them).
    required = " ".join(pyproject["tool"]["hatch"]["metadata"]["hooks"]["custom"]["dependencies"])
    for _command, _argv, module, extra in CASES:
        assert extras[extra], extra
        assert module not in required  # the service wheel does not need it
        assert extra in readme_test_command(), extra
    assert "test" not in extras

"""docs/ARCHITECTURE.md stays short and its code map names every module.

The rule: the code map has one ``###`` section per source folder, its heading the folder in
backticks (``### `service/lessmap/` ``). Inside that section, every module is named by its
path relative to the folder (``runtime/sessions/table.py``, ``robot/options.rs``), so equal
file names in different packages never stand in for each other. A package's ``__init__.py``
is covered by its folder (``runtime/sessions/``); the folder's own by the section heading.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ARCHITECTURE = ROOT / "docs" / "ARCHITECTURE.md"
MAX_WORDS = 1500

#: Source folders the code map covers, and the suffix of their modules.
MAPPED = {
    "service/lessmap/": ".py",
    "schemas/lessmap_schemas/": ".py",
    "clients/python/lessmap_client/": ".py",
    "clients/rust/src/": ".rs",
}


def sections(text: str) -> dict[str, str]:
    """The text of each ``###`` section, by the first backticked name in its heading."""
    found: dict[str, str] = {}
    for part in re.split(r"^###\s+", text, flags=re.MULTILINE)[1:]:
        heading, _, body = part.partition("\n")
        name = re.search(r"`([^`]+)`", heading)
        if name is not None:
            found[name.group(1)] = re.split(r"^##\s", body, flags=re.MULTILINE)[0]
    return found


def expected_names(folder: str, suffix: str) -> list[str]:
    """What the section of ``folder`` must name: module paths, and package folders."""
    base = ROOT / folder
    names: list[str] = []
    for path in sorted(base.rglob(f"*{suffix}")):
        if "__pycache__" in path.parts:
            continue
        relative = path.relative_to(base)
        if path.name == "__init__.py":
            if relative.parent != Path():
                names.append(f"{relative.parent.as_posix()}/")
        else:
            names.append(relative.as_posix())
    return names


def named(name: str, body: str) -> bool:
    """True when ``name`` appears as a whole path, not as the tail of a longer one."""
    return re.search(rf"(?<![\w/.]){re.escape(name)}(?![\w])", body) is not None


def test_the_architecture_fits_in_a_quarter_hour() -> None:
    words = len(ARCHITECTURE.read_text(encoding="utf-8").split())
    assert words <= MAX_WORDS, f"docs/ARCHITECTURE.md has {words} words (at most {MAX_WORDS})"


@pytest.mark.parametrize("folder", sorted(MAPPED))
def test_the_code_map_names_every_module(folder: str) -> None:
    if not (ROOT / folder).is_dir():
        pytest.skip(f"{folder} is not in this checkout")
    found = sections(ARCHITECTURE.read_text(encoding="utf-8"))
    assert folder in found, f"docs/ARCHITECTURE.md has no code-map section '### `{folder}`'"
    missing = [n for n in expected_names(folder, MAPPED[folder]) if not named(n, found[folder])]
    assert not missing, f"the code map's `{folder}` section misses: {', '.join(missing)}"


def test_the_code_map_has_the_benchmarks() -> None:
    assert "benchmarks/" in sections(ARCHITECTURE.read_text(encoding="utf-8"))


def test_the_rule_finds_a_missing_module() -> None:
    body = "`runtime/sessions/table.py` and `robot/options.rs`"
    assert named("runtime/sessions/table.py", body)
    assert not named("sessions/table.py", body)  # only the tail of a longer path
    assert not named("table.py", body)
    assert named("robot/options.rs", body)
    assert not named("options.rs", body)


def test_the_sections_end_at_the_next_heading() -> None:
    text = "### `a/`\n`x.py`\n### `b/`\n`y.py`\n## Other\n`z.py`\n"
    found = sections(text)
    assert found == {"a/": "`x.py`\n", "b/": "`y.py`\n"}

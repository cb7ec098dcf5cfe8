"""Write the JSON Schema of every message, or check that the checked-in ones are current.

Usage: `python -m lessmap_schemas.export [--check] [--out DIR]`. The schemas are generated
from `messages.py` and never edited by hand; CI runs `--check` so they cannot go stale.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap_schemas.keys import WIRE_VERSION
from lessmap_schemas.messages import MESSAGE_TYPES

if TYPE_CHECKING:
    from collections.abc import Sequence

SOURCE_ROOT = Path(__file__).resolve().parent.parent
"""`schemas/` in a source checkout; `site-packages/` once installed."""
DEFAULT_OUT = SOURCE_ROOT / "jsonschema"
"""`schemas/jsonschema/` of a source checkout."""
SCHEMA_BASE = f"https://lessmap.dev/schemas/v{WIRE_VERSION}"
DIALECT = "https://json-schema.org/draft/2020-12/schema"


def json_schema(name: str) -> dict[str, Any]:
    """Return the JSON Schema of one message type.

    `type` and `v` have defaults in Python, but every encoded message carries them, so the
    schema lists them as required.
    """
    model = MESSAGE_TYPES[name]
    schema = model.model_json_schema()
    schema["required"] = ["type", "v", *(f for f in schema.get("required", []) if f != "type")]
    schema["$schema"] = DIALECT
    schema["$id"] = f"{SCHEMA_BASE}/{name}.json"
    schema["title"] = name
    return schema


def render(name: str) -> str:
    """Return the file text of one schema: sorted keys, 2-space indent, trailing newline."""
    return json.dumps(json_schema(name), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def stale_files(out: Path) -> list[str]:
    """Return the names of files in `out` that are missing, differ, or are not generated."""
    expected = {f"{name}.json": render(name) for name in MESSAGE_TYPES}
    stale = [
        file
        for file, text in expected.items()
        if not (out / file).is_file() or (out / file).read_text(encoding="utf-8") != text
    ]
    stale += sorted(path.name for path in out.glob("*.json") if path.name not in expected)
    return stale


def write(out: Path) -> list[Path]:
    """Write every schema into `out` (created if needed) and return the paths written."""
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in MESSAGE_TYPES:
        path = out / f"{name}.json"
        path.write_text(render(name), encoding="utf-8")
        paths.append(path)
    return paths


def default_out() -> Path | None:
    """Return `schemas/jsonschema/` if this package runs from a source checkout, else None.

    Installed, the folder next to the package would be `site-packages/jsonschema/`: the
    jsonschema library itself, which must never be compared with, let alone written to.
    """
    in_checkout = (SOURCE_ROOT / "vectors" / "generate.py").is_file()
    return DEFAULT_OUT if in_checkout else None


def main(argv: Sequence[str] | None = None) -> int:
    """Run the exporter; return the process exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m lessmap_schemas.export",
        description="Generate schemas/jsonschema/<Type>.json from the lessmap message models.",
    )
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if any file is stale"
    )
    parser.add_argument(
        "--out", type=Path, help="schema folder (default: schemas/jsonschema of the checkout)"
    )
    args = parser.parse_args(argv)
    out: Path | None = args.out or default_out()
    if out is None:
        sys.stderr.write(
            f"lessmap_schemas is installed in {SOURCE_ROOT}, not in a source checkout, so there "
            "is no schemas/jsonschema folder to check or write; pass --out DIR\n"
        )
        return 1
    if args.check:
        if not out.is_dir():
            sys.stderr.write(
                f"no schema folder at {out}: run from a source checkout or pass --out DIR\n"
            )
            return 1
        stale = stale_files(out)
        if stale:
            sys.stderr.write(
                f"stale JSON Schemas in {out}: {', '.join(stale)}; "
                "run `python -m lessmap_schemas.export` and commit the result\n"
            )
            return 1
        sys.stdout.write(f"{len(MESSAGE_TYPES)} JSON Schemas in {out} are up to date\n")
        return 0
    for path in write(out):
        sys.stdout.write(f"wrote {path}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

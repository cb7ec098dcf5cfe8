"""Where the language-neutral contract files are: JSON Schemas and golden vectors.

An installed wheel carries them inside the package (``lessmap_schemas/contract/``); a source
checkout (editable install) reads them from ``schemas/jsonschema`` and ``schemas/vectors``, the
very files every other client's tests read.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def contract_dir(kind: str) -> Path:
    """Return the folder of ``"jsonschema"`` or ``"vectors"``.

    Raises:
        ValueError: an unknown kind.
        FileNotFoundError: neither the packaged nor the source-tree folder exists.
    """
    if kind not in {"jsonschema", "vectors"}:
        msg = f"contract files are 'jsonschema' or 'vectors', not {kind!r}"
        raise ValueError(msg)
    for folder in (_PACKAGE / "contract" / kind, _PACKAGE.parent / kind):
        if folder.is_dir():
            return folder
    msg = f"no {kind} folder beside {_PACKAGE} (a broken install?)"
    raise FileNotFoundError(msg)


def vector_files() -> list[Path]:
    """Return the golden vector files, one per message type, sorted by name."""
    return sorted(contract_dir("vectors").glob("*.json"))


def schema_files() -> list[Path]:
    """Return the JSON Schema files, one per message type, sorted by name."""
    return sorted(contract_dir("jsonschema").glob("*.json"))

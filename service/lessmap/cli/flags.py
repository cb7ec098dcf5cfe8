"""Command-line flags derived from pydantic models: one definition per setting.

A field's name, type, description and constraints are its flag, so a new field needs no
second definition.

A field ``session_idle_timeout_s`` becomes ``--session-idle-timeout-s``; a nested model's
field ``limits.max_seq`` becomes ``--limits-max-seq``. Extra spellings (``-m``,
``--idle-timeout``) come from a ``Flag`` in the field's ``Annotated`` metadata. Values stay
strings until the model validates them, so every invalid value is reported the same way,
whatever its source; only the choices of a ``Literal`` or ``Enum`` are checked by argparse.
"""

from __future__ import annotations

import argparse
import enum
import types
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping

    from pydantic.fields import FieldInfo


class Flag:
    """Field metadata: extra flag spellings and the help group, e.g. ``Flag("-m")``."""

    __slots__ = ("group", "metavar", "names")

    def __init__(self, *names: str, group: str | None = None, metavar: str | None = None) -> None:
        self.names = names
        self.group = group
        self.metavar = metavar


class FlagSpec(typing.NamedTuple):
    """One derived flag: where its value goes in the model, and how it is spelled."""

    path: tuple[str, ...]  # ("limits", "max_seq")
    dest: str  # "limits__max_seq": argparse's attribute
    names: tuple[str, ...]  # ("--limits-max-seq",)
    field: FieldInfo
    group: str | None  # help group: the field's ``Flag(group=...)``, or its nested model's

    @property
    def flag(self) -> str:
        """Return the main spelling (the derived long flag)."""
        return self.names[0]


def flag_specs(
    model: type[BaseModel], prefix: tuple[str, ...] = (), group: str | None = None
) -> Iterator[FlagSpec]:
    """Yield the flag of every field of ``model``, nested models' fields included."""
    for name, field in model.model_fields.items():
        path = (*prefix, name)
        nested = _nested_model(field.annotation)
        if nested is not None:
            doc = (nested.__doc__ or name).strip().splitlines()[0].rstrip(".")
            yield from flag_specs(nested, path, f"{name}: {doc}")
            continue
        extra = [m for m in field.metadata if isinstance(m, Flag)]
        names = ("--" + "-".join(path).replace("_", "-"), *(n for f in extra for n in f.names))
        explicit = next((f.group for f in extra if f.group), None)
        yield FlagSpec(path, "__".join(path), names, field, explicit or group)


def add_flags(
    parser: argparse.ArgumentParser,
    model: type[BaseModel],
    *,
    title: str,
    env_prefix: str | None = None,
    exclude: frozenset[str] = frozenset(),
) -> list[FlagSpec]:
    """Add one flag per field of ``model`` (nested fields too) and return them.

    Args:
        parser: the command's parser.
        model: the model whose fields become flags.
        title: help group of the fields that name none in their ``Flag``.
        env_prefix: when given, the help names each field's environment variable.
        exclude: dests to leave out.
    """
    groups: dict[str, Any] = {}  # title -> argument group
    specs = [spec for spec in flag_specs(model) if spec.dest not in exclude]
    for spec in specs:
        group_title = spec.group or title
        if group_title not in groups:
            groups[group_title] = parser.add_argument_group(group_title)
        env = None if env_prefix is None else (env_prefix + spec.dest).upper()
        groups[group_title].add_argument(
            *spec.names, dest=spec.dest, default=argparse.SUPPRESS, **_argument(spec.field, env)
        )
    return specs


def given(args: argparse.Namespace, specs: list[FlagSpec]) -> tuple[dict[str, Any], dict[str, str]]:
    """Return the values of the flags actually given, nested as the model expects.

    Returns:
        The values, and for each dotted field path the flag that set it (for messages).
    """
    values: dict[str, Any] = {}
    origin: dict[str, str] = {}
    for spec in specs:
        if hasattr(args, spec.dest):
            target = values
            for part in spec.path[:-1]:
                target = target.setdefault(part, {})
            target[spec.path[-1]] = getattr(args, spec.dest)
            origin[".".join(spec.path)] = spec.flag
    return values, origin


def _argument(field: FieldInfo, env: str | None) -> dict[str, Any]:
    """Return argparse's keyword arguments for one field."""
    kind = _strip_optional(field.annotation)
    options: dict[str, Any] = {}
    origin = typing.get_origin(kind)
    if origin in {tuple, list}:
        kind = typing.get_args(kind)[0]
        options["action"] = "append"
    if typing.get_origin(kind) is typing.Literal:
        options["choices"] = [str(v) for v in typing.get_args(kind)]
    elif isinstance(kind, type) and issubclass(kind, enum.Enum):
        options["choices"] = [str(m.value) for m in kind]
    elif kind is bool:
        options["action"] = argparse.BooleanOptionalAction
    elif kind in {int, float}:
        options["metavar"] = "N" if kind is int else "X"
    elif kind in {str, Path}:
        options["metavar"] = "PATH" if kind is Path else "TEXT"
    else:
        msg = f"no flag for a field of type {field.annotation!r}"
        raise TypeError(msg)
    if options.get("action") == "append":
        options["metavar"] = "VALUE"
    for flag in (m for m in field.metadata if isinstance(m, Flag) and m.metavar):
        options["metavar"] = flag.metavar
    notes = []
    if field.default_factory is None and field.default not in (None, (), []):
        default = field.default
        notes.append(f"default {default.value if isinstance(default, enum.Enum) else default}")
    if options.get("action") == "append":
        notes.append("repeatable")
    if env is not None:
        notes.append(f"env {env}")
    text = field.description or ""
    if notes:
        text = f"{text} ({'; '.join(notes)})" if text else "; ".join(notes)
    options["help"] = text.replace("%", "%%")
    return options


def _strip_optional(annotation: Any) -> Any:
    if typing.get_origin(annotation) in {typing.Union, types.UnionType}:
        inner = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(inner) == 1:
            return inner[0]
    return annotation


def _nested_model(annotation: Any) -> type[BaseModel] | None:
    kind = _strip_optional(annotation)
    if isinstance(kind, type) and issubclass(kind, BaseModel):
        return kind
    return None


def describe_path(path: tuple[str | int, ...]) -> str:
    """Return a field location as ``limits.max_seq``."""
    return ".".join(str(p) for p in path)


def lookup(values: Mapping[str, Any], path: tuple[str | int, ...]) -> tuple[bool, Any]:
    """Return whether ``values`` holds ``path`` (nested dicts), and the value there."""
    current: Any = values
    for part in path:
        if not isinstance(current, dict) or part not in current:
            return False, None
        current = current[part]
    return True, current

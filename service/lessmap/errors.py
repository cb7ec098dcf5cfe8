"""Errors of the lessmap service package."""

from __future__ import annotations

from lessmap.core.errors import GraphError, StaleFrameError

__all__ = ["ConfigError", "DatasetError", "GraphError", "StaleFrameError", "UsageError"]


class ConfigError(ValueError):
    """A setting or command-line option is invalid."""


class UsageError(ConfigError):
    """A flag's value is of the wrong kind or out of range: the command line is wrong (exit 2)."""


#: Pydantic error types of a value's own form (kind, range, choice), not of the world.
USAGE_ERROR_TYPES = frozenset(
    {
        "int_parsing",
        "int_from_float",
        "float_parsing",
        "bool_parsing",
        "finite_number",
        "greater_than",
        "greater_than_equal",
        "less_than",
        "less_than_equal",
        "literal_error",
        "enum",
    }
)


def setting_error(msg: str, error_type: str, *, from_flag: bool) -> ConfigError:
    """Return the error for an invalid setting: a usage error when a flag gave a bad form."""
    if from_flag and error_type in USAGE_ERROR_TYPES:
        return UsageError(msg)
    return ConfigError(msg)


class DatasetError(ValueError):
    """A frames file (or a companion file) is malformed."""

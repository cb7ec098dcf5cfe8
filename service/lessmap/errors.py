"""Errors of the lessmap service package."""

from __future__ import annotations

from lessmap.core.errors import GraphError, StaleFrameError

__all__ = ["ConfigError", "DatasetError", "GraphError", "StaleFrameError"]


class ConfigError(ValueError):
    """A setting or command-line option is invalid."""


class DatasetError(ValueError):
    """A frames file (or a companion file) is malformed."""

"""Errors raised by the partitioning core."""

from __future__ import annotations


class GraphError(ValueError):
    """A CovGraph or partitioner input or state is invalid."""


class StaleFrameError(GraphError):
    """A frame's seq is not after the last applied one (duplicate or out of order)."""

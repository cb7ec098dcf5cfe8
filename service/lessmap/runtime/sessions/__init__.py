"""The robot sessions of one shard (``SessionTable``) and the pieces it orchestrates.

``table`` applies the rules; ``seq`` holds the pure per-session seq rules, ``catchup`` the
holds that wait for a robot's cache, ``durability`` checkpoints, resuming and eviction,
``limits`` the work budgets, ``wire`` the conversion to wire messages, ``policy`` the
settings grouped by the kind of decision. Modules of the runtime import these modules
directly; this package re-exports their public names for the tests and the benchmarks.
"""

from lessmap.runtime.sessions.durability import commit_checkpoints
from lessmap.runtime.sessions.model import (
    FRAME_COST,
    CatchupRequest,
    Outcome,
    Rejection,
    RobotSession,
)
from lessmap.runtime.sessions.policy import (
    CatchupPolicy,
    Clocks,
    DurabilityPolicy,
    Identity,
    Segmenting,
    SessionLimits,
    SharedBudgets,
)
from lessmap.runtime.sessions.table import SessionTable
from lessmap.runtime.sessions.wire import summary_of, wire_area_graph, wire_transition

__all__ = [
    "FRAME_COST",
    "CatchupPolicy",
    "CatchupRequest",
    "Clocks",
    "DurabilityPolicy",
    "Identity",
    "Outcome",
    "Rejection",
    "RobotSession",
    "Segmenting",
    "SessionLimits",
    "SessionTable",
    "SharedBudgets",
    "commit_checkpoints",
    "summary_of",
    "wire_area_graph",
    "wire_transition",
]

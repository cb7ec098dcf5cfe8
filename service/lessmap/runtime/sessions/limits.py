"""Limits and work budgets of one table, checked before a frame reaches the core.

Invariants:

1. Memory is bounded: at most ``max_sessions`` open sessions per shard and ``max_nodes``
   features per CovGraph; past either, the message is refused with an error.
2. A frame costs at most ``max_pairs_per_frame`` pair updates (k features make k(k-1)/2,
   k counted after the session's sampling, ``kept_features``; ``LIMIT_EXCEEDED``); a
   session holds at most ``max_edges_per_session`` edges and the instance
   ``ledger.max_edges_total`` (``GRAPH_LIMIT``), a graph counted by what it holds in edges'
   worth (``Segmenter.memory_edges``), so the budgets bound memory too.
3. The edge checks are conservative: a frame counts as if every pair of its features were a
   new edge; the exact count is read only when that bound says the frame could break one.
4. New sessions are admitted at ``admission.rate_per_s`` per fleet (a token bucket).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.runtime.budget import pairs_of
from lessmap_schemas.errors import ErrorCode

if TYPE_CHECKING:
    from lessmap.core.segmenter import Segmenter
    from lessmap.runtime.sessions.model import RobotSession
    from lessmap.runtime.sessions.policy import Segmenting, SessionLimits, SharedBudgets
    from lessmap_schemas.messages import Frame


def kept_features(segmenter: Segmenter | Segmenting, features: int) -> int:
    """Features of a frame of ``features`` that reach the session's CovGraph at most."""
    cap = segmenter.max_features_kept
    return min(features, cap) if cap else features


def kept_pairs(segmenter: Segmenter | Segmenting, features: int) -> int:
    """Pair updates a frame of ``features`` can cause in the session, after its sampling."""
    return pairs_of(kept_features(segmenter, features))


class Budgets:
    """The limits of one table and its share of the instance's budgets."""

    def __init__(self, limits: SessionLimits, shared: SharedBudgets) -> None:
        self._max_pairs = limits.max_pairs_per_frame  # 0: no budget
        self._max_edges = limits.max_edges_per_session  # 0: no budget
        self._max_nodes = limits.max_nodes
        self._ledger = shared.ledger
        self._slot = shared.slot
        self._admission = shared.admission
        # Edges are counted only when a budget reads them.
        self.counts_edges = bool(self._max_edges) or self._ledger is not None

    def admission_refusal(self, fleet: str, now_s: float) -> str | None:
        """Why a new session of ``fleet`` may not open now (invariant 4), or None."""
        admission = self._admission
        if admission is None or admission.allow(fleet, now_s):
            return None
        return (
            f"fleet {fleet!r} opens more than {admission.rate_per_s:g} new sessions "
            f"a second (burst {admission.burst}); retry later"
        )

    def set_edges(self, session: RobotSession, edges: int) -> None:
        """Record a session's edges (0 when it leaves memory) in the instance's ledger."""
        if self._ledger is not None:
            self._ledger.add(self._slot, edges - session.edges)
        session.edges = edges

    def charge(self, session: RobotSession, features: int) -> None:
        """Count an applied frame's pairs as new edges (an upper bound until the decision)."""
        if self.counts_edges:
            kept = kept_features(session.segmenter, features)
            self.set_edges(session, session.edges + pairs_of(kept))

    def recount(self, session: RobotSession) -> None:
        """Take the session's exact edges' worth (after a decision)."""
        if self.counts_edges:
            self.set_edges(session, session.segmenter.memory_edges)

    def refusal(self, session: RobotSession, frame: Frame) -> tuple[ErrorCode, str] | None:
        """Why a frame may not reach the session's core (invariants 1-3), or None."""
        p = session.segmenter
        kept = kept_features(p, len(frame.features))
        refusal = self._over_budget(session, kept)
        if refusal is not None:
            return refusal
        max_nodes = self._max_nodes
        if p.node_count + kept > max_nodes and (
            p.node_count + min(kept, sum(1 for f in set(frame.features) if not p.feature_known(f)))
            > max_nodes
        ):  # counting the new features only when the cheap bound says it could matter
            return (ErrorCode.GRAPH_LIMIT, f"CovGraph would exceed {max_nodes} features")
        return None

    def _over_budget(self, session: RobotSession, features: int) -> tuple[ErrorCode, str] | None:
        pairs = pairs_of(features)
        if self._max_pairs and pairs > self._max_pairs:
            return (
                ErrorCode.LIMIT_EXCEEDED,
                f"{features} features make {pairs} feature pairs, over the budget "
                f"max_pairs_per_frame={self._max_pairs}",
            )
        ledger = self._ledger
        if not self.counts_edges:
            return None
        if (self._max_edges and session.edges + pairs > self._max_edges) or (
            ledger is not None and ledger.total() + pairs > ledger.max_edges_total
        ):
            self.set_edges(session, session.segmenter.memory_edges)
            if self._max_edges and session.edges + pairs > self._max_edges:
                return (
                    ErrorCode.GRAPH_LIMIT,
                    f"CovGraph holds {session.edges} edges' worth; a frame of {features} features "
                    f"could add {pairs}, over the budget max_edges_per_session={self._max_edges}",
                )
            if ledger is not None and ledger.total() + pairs > ledger.max_edges_total:
                return (
                    ErrorCode.GRAPH_LIMIT,
                    f"the instance holds {ledger.total()} edges; a frame of {features} features "
                    f"could add {pairs}, over the budget "
                    f"max_edges_total={ledger.max_edges_total}",
                )
        return None

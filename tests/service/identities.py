"""Every Transition on the bus, and the identities published with different content.

A transition is identified by (fleet, robot, session, incarnation, closed.id). A repeat
with the same content is harmless (a restart computes it again); a repeat with other
content is a conflict: an application keying transitions by identity would overwrite one
history with another. Who published it (instance, epoch) is not content.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import Transition

if TYPE_CHECKING:
    import zenoh

Identity = tuple[str, str, str, int, int]
NOT_CONTENT = {"instance", "epoch"}


def identity_of(t: Transition) -> Identity:
    # getattr: the same check judges a contract without incarnations (always 0 there).
    return (t.fleet, t.robot, t.session, getattr(t, "incarnation", 0), t.closed.id)


def content_of(t: Transition) -> dict[str, Any]:
    return {k: v for k, v in t.model_dump().items() if k not in NOT_CONTENT}


class TransitionLedger:
    """Subscribes to a fleet's transitions and keeps every one, duplicates included."""

    def __init__(self, session: zenoh.Session, fleet: str) -> None:
        self._lock = threading.Lock()
        self.transitions: list[Transition] = []
        self.undecodable = 0
        self._sub = session.declare_subscriber(keys.transitions(fleet, "*"), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            transition = decode(sample.payload.to_bytes(), Transition)
        except WireError:
            with self._lock:
                self.undecodable += 1
            return
        with self._lock:
            self.transitions.append(transition)

    def close(self) -> None:
        self._sub.undeclare()

    def conflicts(self) -> list[Identity]:
        """Identities published with more than one content, in order of first publication."""
        seen: dict[Identity, dict[str, Any]] = {}
        found: dict[Identity, None] = {}
        with self._lock:
            transitions = list(self.transitions)
        for t in transitions:
            key, content = identity_of(t), content_of(t)
            first = seen.setdefault(key, content)
            if first != content:
                found[key] = None
        return list(found)

    def distinct(self) -> list[Transition]:
        """The first copy of each identity, in order of publication."""
        kept: dict[Identity, Transition] = {}
        with self._lock:
            for t in self.transitions:
                kept.setdefault(identity_of(t), t)
        return list(kept.values())

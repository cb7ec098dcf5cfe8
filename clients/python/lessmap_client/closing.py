"""Ending robot sessions: keep the publication caches until the service confirms the ends.

A robot's cache is the only copy of the frames the service has not applied yet: when a
partition moves between instances as a robot ends its session, the new owner fetches them
from it (contract section 6, rules 8 and 9). So the ends are confirmed first, by the robots'
``SessionState``. Rules of this file:

1. It never raises and never waits past the deadline (a query is bounded by what is left).
2. One state query per Zenoh session and fleet per poll, whatever the number of robots
   waiting: a fleet's robots are asked with one wildcard key.
3. A robot is confirmed when the service's current state shows its session closed, or open
   with every frame up to the robot's last seq applied (then only the end is missing: it is
   put again, which the service ignores if it had it, contract section 6 rule 3).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lessmap_client.fencing import current_states
from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.errors import WireError
from lessmap_schemas.messages import SessionState

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from lessmap_client.transport import Transport

log = logging.getLogger(__name__)

#: Pause before each poll. The first is short (a live end is handled within a receiver
#: sweep, 10-50 ms); later ones grow, so a slow take-over costs few queries.
POLL_DELAYS_S = (0.02, 0.05, 0.1, 0.2, 0.25)
#: A session open with every frame applied gets this long for its end to arrive before the
#: end is put again (it may have been dropped with the frames queued at a deposed owner).
END_GRACE_S = 0.3
_QUERY_MAX_S = 1.0
_INSTANCES_QUERY_S = 0.5


@dataclass(eq=False, slots=True)
class PendingEnd:
    """A session end sent and not yet confirmed (one per robot publisher).

    Attributes:
        fleet: fleet of the robot.
        robot: the robot.
        session: the session ended.
        last_seq: its last frame (sessions without a frame need no confirmation).
        transport: what the state queries go through.
        route: the network under the transport (the Zenoh session): one query serves every
            robot of a fleet on it.
        served: whether the publisher knows a live service instance (its tokens).
        closed_by_service: whether the service reported the session closed meanwhile.
        resend: puts the end again.
    """

    fleet: str
    robot: str
    session: str
    last_seq: int
    transport: Transport
    route: object
    served: Callable[[], bool]
    closed_by_service: Callable[[], bool]
    resend: Callable[[], object]
    caught_up_at: float | None = None


@dataclass(frozen=True, slots=True)
class Unconfirmed:
    """Ends left unconfirmed, and why (for the caller's one warning line)."""

    ends: list[PendingEnd]
    reason: str


def confirm_ends(ends: Sequence[PendingEnd], timeout_s: float) -> list[Unconfirmed]:
    """Wait until the service confirms every end, at most ``timeout_s``; return the rest.

    Gives up at once on the robots of a network with no live service instance (nobody can
    confirm, and waiting would only delay the caller) or whose transport fails.
    """
    deadline = time.monotonic() + timeout_s
    waiting = list(ends)
    given_up: list[Unconfirmed] = []
    delays = iter(POLL_DELAYS_S)
    while waiting and (now := time.monotonic()) < deadline:
        time.sleep(min(next(delays, POLL_DELAYS_S[-1]), deadline - now))
        still: list[PendingEnd] = []
        for group in _by_route(waiting):
            remaining = deadline - time.monotonic()
            if not _anyone_alive(group, remaining):
                given_up.append(Unconfirmed(group, "no live lessmap instance"))
                continue
            try:
                states = _states(group, max(0.05, min(_QUERY_MAX_S, remaining)))
            except Exception as exc:  # zenoh.ZError, a closed session: nobody to ask
                given_up.append(Unconfirmed(group, f"state query failed ({exc})"))
                continue
            now = time.monotonic()
            still += [end for end in group if not _confirmed(end, states, now)]
        waiting = still
    # Out of time: a session with every frame applied lacks only its end; the cache is not
    # needed for it any more.
    late = []
    for end in waiting:
        if end.caught_up_at is not None:
            end.resend()
        else:
            late.append(end)
    if late:
        given_up.append(Unconfirmed(late, f"not confirmed within {timeout_s:g} s"))
    return given_up


def _by_route(ends: list[PendingEnd]) -> list[list[PendingEnd]]:
    groups: dict[int, list[PendingEnd]] = {}
    for end in ends:
        groups.setdefault(id(end.route), []).append(end)
    return list(groups.values())


def _anyone_alive(group: list[PendingEnd], remaining_s: float) -> bool:
    """A live instance per the publishers' tokens, else per one liveliness query.

    The query covers a publisher closed so soon after it was made that the tokens had not
    reached it yet.
    """
    if any(end.served() for end in group):
        return True
    try:
        return bool(group[0].transport.instances(max(0.05, min(_INSTANCES_QUERY_S, remaining_s))))
    except Exception:  # a closed session: nobody to ask
        return False


def _states(group: list[PendingEnd], timeout_s: float) -> dict[tuple[str, str], SessionState]:
    """The current state of the group's robots: one query per fleet (wildcard if several)."""
    robots: dict[str, set[str]] = {}
    for end in group:
        robots.setdefault(end.fleet, set()).add(end.robot)
    found = []
    for fleet, names in robots.items():
        key = keys.state(fleet, next(iter(names)) if len(names) == 1 else "*")
        for reply_key, payload in group[0].transport.get(key, timeout_s):
            try:
                found.append(decode(payload, SessionState))
            except WireError as exc:
                log.debug("skipped an undecodable reply on %s: %s", reply_key, exc)
    # Of several replies for a robot (an old and a new owner), the highest epoch is current.
    return {(s.fleet, s.robot): s for s in current_states(found)}


def _confirmed(end: PendingEnd, states: dict[tuple[str, str], SessionState], now: float) -> bool:
    if end.closed_by_service():
        return True  # the service closed it (a SESSION_CLOSED report): nothing more will apply
    state = states.get((end.fleet, end.robot))
    if state is None or state.session != end.session:
        # Nobody holds the robot yet (a take-over in progress), or only an earlier session
        # of it: this session's frames are still to be fetched from the cache. Another
        # publisher's session is no proof either: it may be older than this one.
        return False
    if not state.open:
        return True
    if state.last_seq is None or state.last_seq < end.last_seq:
        end.caught_up_at = None
        return False
    if end.caught_up_at is None:
        end.caught_up_at = now
        return False
    if now - end.caught_up_at < END_GRACE_S:
        return False
    end.resend()
    return True

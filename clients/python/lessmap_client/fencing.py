"""Which of several answers is current: ownership epochs (contract section 2a).

Each partition's owner stamps what it publishes and answers with its ownership epoch; a new
owner's epoch is above every earlier one. Of several ``SessionState`` replies for one robot
(an old and a new owner during a hand-over) the highest epoch is current. Events are fenced
in ``Subscription`` and in ``RobotPublisher``, where they are received.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

    from lessmap_schemas.messages import AreaGraph, SessionState


def current_states(states: Iterable[SessionState]) -> list[SessionState]:
    """Keep one state per robot: the highest ``epoch``, then the most ``frames_applied``.

    Robots stay in the order of their first reply.
    """
    best: dict[tuple[str, str], SessionState] = {}
    for state in states:
        robot = (state.fleet, state.robot)
        kept = best.get(robot)
        if kept is None or (state.epoch, state.frames_applied) > (kept.epoch, kept.frames_applied):
            best[robot] = state
    return list(best.values())


def current_area_graphs(graphs: Iterable[AreaGraph]) -> list[AreaGraph]:
    """Keep one area graph per robot: the highest ``epoch``, then the most frames.

    Robots stay in the order of their first reply.
    """
    best: dict[tuple[str, str], AreaGraph] = {}
    for graph in graphs:
        robot = (graph.fleet, graph.robot)
        kept = best.get(robot)
        if kept is None or (graph.epoch, _frames(graph)) > (kept.epoch, _frames(kept)):
            best[robot] = graph
    return list(best.values())


def _frames(graph: AreaGraph) -> int:
    return sum(area.frames for area in graph.areas)

"""A live terminal view of a fleet: one row per robot, new transitions as they arrive."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lessmap_client.fleet_areas import FleetGraph
    from lessmap_schemas.messages import SessionState, Transition


_KEEP = 100_000  # transitions remembered by a view


def why(reason: str, ncut: float | None, lambda2: float | None) -> str:
    """Say, in words, what made the service decide a transition (its ``reason``)."""
    if reason == "SPECTRAL" and ncut is not None and lambda2 is not None:
        return f"a weak cut of the CovGraph (Ncut {ncut:.3f}, λ2 {lambda2:.3f})"
    if reason == "DISCONNECTED":
        return "the CovGraph fell apart (no feature seen on both sides)"
    if reason == "RECOGNISED":
        return "its last frames fit an area it mapped before"
    return reason


def areas_crossed(left_area: int, area: int, *, revisit: bool) -> str:
    """``area 2 -> area 5`` (``again`` when the robot had mapped area 5 before)."""
    return f"area {left_area} -> area {area}" + (" again" if revisit else "")


def coalesced(batch_frames: int) -> str:
    """Empty, or that the decision covered several frames (the service was behind)."""
    return f"; decided over {batch_frames} coalesced frames" if batch_frames > 1 else ""


@dataclass(slots=True)
class RobotRow:
    """What the view knows of one robot."""

    fleet: str
    robot: str
    session: str = ""
    submap: int = 0
    area: int = 0
    frames: int | None = None  # from state queries; None until one answered
    transitions: int = 0
    last_seq: int | None = None
    last_reason: str = ""
    ncut: float | None = None
    lambda2: float | None = None
    open: bool = True
    place: str | None = None  # the fleet area of ``area`` (its first member), when followed


class FleetView:
    """Folds transitions and session states into rows, and renders them as text."""

    def __init__(self) -> None:
        self.rows: dict[tuple[str, str], RobotRow] = {}
        self.log: list[str] = []  # one line per transition, newest last (bounded)
        self.transitions: list[Transition] = []  # every transition seen (bounded)
        self.started_s = time.monotonic()
        self.shared_places: list[str] = []  # fleet areas several robots have been in

    def _row(self, fleet: str, robot: str) -> RobotRow:
        key = (fleet, robot)
        if key not in self.rows:
            self.rows[key] = RobotRow(fleet, robot)
        return self.rows[key]

    def add_transition(self, t: Transition) -> str:
        """Record a transition; return its one-line description."""
        row = self._row(t.fleet, t.robot)
        if row.session != t.session:
            row.session, row.transitions = t.session, 0
        row.submap, row.area = t.opened.id, t.area
        row.transitions += 1
        row.last_seq, row.last_reason, row.ncut, row.lambda2 = t.seq, t.reason, t.ncut, t.lambda2
        line = (
            f"{t.fleet}/{t.robot}: {areas_crossed(t.left_area, t.area, revisit=t.revisit)} "
            f"at frame {t.boundary_seq} (detected at {t.seq}), {t.reason}: "
            f"{why(t.reason, t.ncut, t.lambda2)}; submap {t.closed.id} "
            f"({len(t.closed.features)} features, {t.closed.frame_count} frames) -> "
            f"submap {t.opened.id}{coalesced(t.batch_frames)}"
        )
        self.log.append(line)
        del self.log[:-200]
        self.transitions.append(t)
        del self.transitions[:-_KEEP]
        return line

    def add_state(self, state: SessionState) -> None:
        """Record a session state answer."""
        row = self._row(state.fleet, state.robot)
        if row.session and row.session != state.session and state.open is False:
            return  # an older session's final state: the row follows the newer one
        row.session = state.session
        row.frames = state.frames_applied
        row.submap, row.area = state.current_submap.id, state.current_area
        row.transitions = state.transitions
        row.open = state.open

    def add_fleet_graph(self, fleet: str, graph: FleetGraph) -> None:
        """Record the fleet's places (``fleet_area_graph``): each robot's current one."""
        for (row_fleet, robot), row in self.rows.items():
            if row_fleet == fleet and (robot, row.area) in graph.area_of:
                place_robot, place_area = graph.key_of(robot, row.area)
                row.place = f"{place_robot}:{place_area}"
        self.shared_places = [
            f"{fleet} place {node.members[0][0]}:{node.members[0][1]}: "
            + ", ".join(f"{robot}:{area}" for robot, area in node.members)
            for node in graph.nodes
            if len(graph.robots_in(node.area)) > 1
        ]

    def table(self) -> str:
        """Render the rows as a fixed-width table."""
        places = any(row.place is not None for row in self.rows.values())
        header = (
            f"{'robot':<24} {'session':<14} {'submap':>6} {'area':>5} {'frames':>7} {'trans':>5} "
            f"{'last':>6} {'reason':<12} {'Ncut':>6} {'λ2':>6}"
            + (f" {'place':<16}" if places else "")
        )
        lines = [header, "-" * len(header)]
        for (fleet, robot), row in sorted(self.rows.items()):
            name = f"{fleet}/{robot}"[:24]
            lines.append(
                f"{name:<24} {row.session[-14:]:<14} {row.submap:>6} {row.area:>5} "
                f"{'-' if row.frames is None else row.frames:>7} {row.transitions:>5} "
                f"{'-' if row.last_seq is None else row.last_seq:>6} {row.last_reason:<12} "
                f"{_num(row.ncut):>6} {_num(row.lambda2):>6}"
                + (f" {row.place or '-':<16}" if places else "")
                + ("" if row.open else "  (closed)")
            )
        return "\n".join(lines)


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"

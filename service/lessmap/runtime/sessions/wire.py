"""Core records to wire messages: session states, submaps, area graphs, transitions."""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap_schemas.messages import (
    AreaGraph,
    AreaNode,
    Passage,
    SessionState,
    SubmapSummary,
    Transition,
)
from lessmap_schemas.partition import partition_of

if TYPE_CHECKING:
    from lessmap.core import Submap
    from lessmap.core.areas.graph import AreaGraph as CoreAreaGraph
    from lessmap.core.segmenter import SegmentChange
    from lessmap.runtime.sessions.model import RobotSession


def summary_of(submap: Submap) -> SubmapSummary:
    """Convert a core submap to its wire summary."""
    return SubmapSummary(
        id=submap.id,
        first_seq=submap.first_seq,
        last_seq=submap.last_seq,
        frame_count=submap.frame_count,
        features=list(submap.features),
    )


def session_state(
    session: RobotSession, instance: str, *, is_open: bool, epoch: int = 1
) -> SessionState:
    """Return a session's state as the wire message."""
    p = session.segmenter
    return SessionState(
        fleet=session.fleet,
        robot=session.robot,
        session=session.session,
        incarnation=session.incarnation,
        instance=instance,
        epoch=epoch,
        open=is_open,
        last_seq=p.last_seq,
        frames_applied=session.applied_before + p.frames_applied,
        frames_duplicate=session.frames_duplicate,
        frames_missing=session.frames_missing,
        frames_rejected=session.frames_rejected,
        transitions=session.transitions_before + p.transitions,
        method=p.method.wire,
        current_area=p.current_area,
        current_submap=summary_of(p.current_submap()),
        closed_submaps=[summary_of(s) for s in p.closed_submaps],
        nodes=p.node_count,
        edges=p.edge_count,
    )


def session_area_graph(session: RobotSession, instance: str, *, epoch: int = 1) -> AreaGraph:
    """Return a session's areas and passages as the wire message."""
    return wire_area_graph(
        session.fleet,
        session.robot,
        session.session,
        session.segmenter.area_graph(),
        method=session.segmenter.method.wire,
        instance=instance,
        epoch=epoch,
    )


def wire_area_graph(
    fleet: str,
    robot: str,
    session: str,
    graph: CoreAreaGraph,
    *,
    method: str,
    instance: str,
    epoch: int,
) -> AreaGraph:
    """Convert a core area graph to the wire message."""
    return AreaGraph(
        fleet=fleet,
        robot=robot,
        session=session,
        instance=instance,
        epoch=epoch,
        method=method,
        areas=[
            AreaNode(
                id=node.area,
                frames=node.frames,
                # A listed area holds frames, so the robot was there at least once.
                visits=max(1, node.visits),
                first_seq=node.first_seq,
                last_seq=node.last_seq,
                features=list(node.features),
            )
            for node in graph.nodes
        ],
        passages=[
            Passage(
                a=edge.a,
                b=edge.b,
                a_to_b=edge.a_to_b,
                b_to_a=edge.b_to_a,
                boundary_features=list(edge.boundary_features),
            )
            for edge in graph.edges
        ],
    )


def wire_transition(
    session: RobotSession, change: SegmentChange, instance: str, epoch: int = 1
) -> Transition:
    """Convert a change of a session's segmenter to the wire message."""
    transition = change.transition
    return Transition(
        fleet=session.fleet,
        robot=session.robot,
        session=session.session,
        incarnation=session.incarnation,
        seq=transition.seq,
        boundary_seq=transition.boundary_seq,
        stamp_s=transition.stamp_s,
        reason=change.reason,
        ncut=transition.ncut,
        lambda2=transition.lambda2,
        closed=summary_of(transition.closed),
        opened=summary_of(transition.opened),
        boundary_features=list(transition.boundary_features),
        area=change.area,
        left_area=change.left_area,
        revisit=change.revisit_of is not None,
        batch_frames=transition.batch_frames,
        instance=instance,
        partition=partition_of(session.fleet, session.robot),
        epoch=epoch,
    )

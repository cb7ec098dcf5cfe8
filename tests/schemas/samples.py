"""Representative messages of every type, shared by the schema tests."""

from __future__ import annotations

from lessmap_schemas import (
    Error,
    ErrorCode,
    Frame,
    Health,
    Message,
    SessionEnd,
    SessionState,
    Submap,
    SubmapSummary,
    Transition,
)

CLOSED = SubmapSummary(id=0, first_seq=0, last_seq=41, frame_count=40, features=[1, 2, 3])
OPENED = SubmapSummary(id=1, first_seq=38, last_seq=42, frame_count=5, features=[3, 2**63 - 1])

FRAME = Frame(
    session="run-1",
    seq=42,
    stamp_s=1718000000.25,
    features=[3, 17, 17, 2**40],
    pose=(1.5, -2.25, 0.75),
)


def samples() -> list[Message]:
    """Return at least one message of each type, with edge values."""
    return [
        FRAME,
        Frame(session="s", seq=0, stamp_s=-1.0, features=[]),
        Frame(session="s_" * 32, seq=2**53 - 1, stamp_s=0.0, features=[2**63 - 1, 0]),
        SessionEnd(session="run-1", last_seq=42, stamp_s=1718000100.5),
        SessionEnd(session="run-1", last_seq=None, stamp_s=0.0),
        Transition(
            fleet="warehouse",
            robot="amr-7",
            session="run-1",
            seq=42,
            boundary_seq=38,
            stamp_s=1718000000.25,
            reason="SPECTRAL",
            ncut=0.125,
            lambda2=0.03,
            closed=CLOSED,
            opened=OPENED,
            boundary_features=[3],
            batch_frames=1,
            instance="lessmap-a1",
        ),
        Transition(
            fleet="warehouse",
            robot="amr-7",
            session="run-1",
            seq=50,
            boundary_seq=50,
            stamp_s=1718000003.0,
            reason="DISCONNECTED",
            ncut=None,
            lambda2=None,
            closed=CLOSED,
            opened=OPENED,
            boundary_features=[],
            batch_frames=4,
            instance="lessmap-a1",
        ),
        Error(
            fleet="warehouse",
            robot="amr-7",
            session="run-1",
            code=ErrorCode.SEQ_GAP,
            detail="frames 43..45 missing",
            seq=46,
            stamp_s=1718000001.0,
            instance="lessmap-a1",
        ),
        Error(
            fleet=None,
            robot=None,
            session=None,
            code=ErrorCode.MALFORMED,
            detail="x" * 1024,
            seq=None,
            stamp_s=1718000001.0,
            instance="lessmap-a1",
        ),
        SessionState(
            fleet="warehouse",
            robot="amr-7",
            session="run-1",
            instance="lessmap-a1",
            open=True,
            last_seq=42,
            frames_applied=43,
            frames_duplicate=2,
            frames_missing=3,
            frames_rejected=1,
            transitions=1,
            current_submap=OPENED,
            closed_submaps=[CLOSED],
            nodes=43,
            edges=310,
        ),
        Submap(fleet="warehouse", robot="amr-7", session="run-1", summary=CLOSED, open=False),
        Health(instance="lessmap-a1", version="0.1.0", sessions=3, uptime_s=12.5, frames_applied=9),
    ]

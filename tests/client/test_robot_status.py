"""A robot knows what the service did with its frames: status, on_error, state(), new sessions.

The first tests run on the in-process ``FakeBus`` (what a user's unit test does); the last
ones against a real ``lessmap serve`` on loopback.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap_client import connect
from lessmap_client.errors import SessionClosedError
from lessmap_client.testing import FakeBus, make_error, make_state
from lessmap_schemas import keys
from lessmap_schemas.codec import encode, encoding
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Error, SessionEnd
from tests.conftest import wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    from tests.conftest import ServeProcess

pytestmark = pytest.mark.timeout(120)

F, R = "warehouse", "amr-7"


def test_an_injected_error_reaches_on_error_and_status_off_the_injecting_thread() -> None:
    bus = FakeBus()
    seen: list[tuple[Error, str]] = []
    with bus.connect() as conn:
        robot = conn.robot(
            F, R, on_error=lambda e: seen.append((e, threading.current_thread().name))
        )
        for _ in range(10):
            robot.publish([1, 2, 3])
        assert robot.status.errors == {}
        bus.publish_error(
            make_error(F, R, "SEQ_GAP", "10 frame(s) missing", session=robot.session_id, seq=20)
        )
        assert robot.flush_errors(5.0)
        status = robot.status
        assert status.count(ErrorCode.SEQ_GAP) == status.count("SEQ_GAP") == 1
        assert status.last_error is not None
        assert status.last_error.seq == 20
        assert (status.last_seq, status.frames_sent, status.closed_by_service) == (9, 10, False)
        assert len(seen) == 1
        assert seen[0][0].code == ErrorCode.SEQ_GAP
        assert seen[0][1] != threading.current_thread().name  # the robot's own thread


def test_reports_about_other_sessions_or_robots_are_not_counted() -> None:
    bus = FakeBus()
    with bus.connect() as conn, conn.robot(F, R) as robot, conn.robot(F, "other") as other:
        robot.publish([1])
        bus.publish_error(make_error(F, R, "SESSION_CLOSED", session="someone-else", seq=0))
        bus.publish_error(make_error(F, "other", "GRAPH_LIMIT", session=other.session_id))
        assert robot.flush_errors(5.0)
        assert other.flush_errors(5.0)
        assert robot.status.errors == {}
        assert not robot.status.closed_by_service
        assert other.status.errors == {"GRAPH_LIMIT": 1}
        assert robot.publish([2]) == 1  # still the same session


def test_session_closed_without_auto_new_session_raises_then_new_session_continues() -> None:
    bus = FakeBus()
    with bus.connect() as conn, conn.robot(F, R, auto_new_session=False) as robot:
        first = robot.session_id
        robot.publish([1])
        robot.publish([2])
        bus.publish_error(make_error(F, R, "SESSION_CLOSED", session=first, seq=1))
        assert robot.flush_errors(5.0)
        assert robot.status.closed_by_service
        with pytest.raises(SessionClosedError, match="closed session") as caught:
            robot.publish([3])
        assert isinstance(caught.value, RuntimeError)
        assert caught.value.session_id == first
        assert caught.value.error is not None
        assert caught.value.error.code == ErrorCode.SESSION_CLOSED
        second = robot.new_session()
        assert second != first
        assert robot.publish([3]) == 0
        assert robot.status.sessions == 2
    frames = bus.frames(F, R)
    assert [(f.session, f.seq) for f in frames] == [(first, 0), (first, 1), (second, 0)]
    # The service had closed the first session: only the second one is ended.
    assert [e.session for e in bus.session_ends(F, R)] == [second]


def test_session_closed_with_auto_new_session_starts_a_new_one() -> None:
    bus = FakeBus()
    with bus.connect() as conn, conn.robot(F, R) as robot:  # auto_new_session by default
        first = robot.session_id
        for _ in range(3):
            robot.publish([1, 2])
        bus.publish_error(make_error(F, R, "SESSION_CLOSED", session=first, seq=2))
        assert robot.flush_errors(5.0)
        assert robot.status.closed_by_service
        assert robot.publish([5]) == 0
        status = robot.status
        assert status.session_id != first
        assert (status.sessions, status.closed_by_service, status.next_seq) == (2, False, 1)
        # A late report about the old session does not start a third one.
        bus.publish_error(make_error(F, R, "SESSION_CLOSED", session=first, seq=2))
        assert robot.flush_errors(5.0)
        assert robot.publish([6]) == 1
        assert robot.status.sessions == 2
        assert robot.status.count("SESSION_CLOSED") == 2


def test_auto_new_session_never_takes_the_robot_over_from_another_publisher() -> None:
    bus = FakeBus()
    with bus.connect() as conn, conn.robot(F, R) as robot:
        robot.publish([1])
        bus.set_state(make_state(F, R, session="the-other-publisher", open=True))
        bus.publish_error(make_error(F, R, "SESSION_CLOSED", session=robot.session_id, seq=0))
        assert robot.flush_errors(5.0)
        with pytest.raises(SessionClosedError, match="the-other-publisher"):
            robot.publish([2])


def test_state_answers_for_the_robots_own_session_only() -> None:
    bus = FakeBus()
    with bus.connect() as conn, conn.robot(F, R) as robot:
        assert robot.state(0.1) is None
        bus.set_state(make_state(F, R, session=robot.session_id, frames_applied=7))
        state = robot.state(0.1)
        assert state is not None
        assert state.frames_applied == 7
        bus.set_state(make_state(F, R, session="another", frames_applied=3))
        assert robot.state(0.1) is None


def test_on_error_may_query_fail_and_close_without_hanging() -> None:
    bus = FakeBus()
    calls: list[object] = []
    with bus.connect() as conn:

        def handler(error: Error) -> None:
            calls.append(robot.state(0.1))
            if len(calls) == 1:
                msg = "a bug in the user's callback"
                raise ValueError(msg)
            robot.close()

        robot = conn.robot(F, R, on_error=handler)
        robot.publish([1])
        bus.publish_error(make_error(F, R, "GRAPH_LIMIT", session=robot.session_id))
        bus.publish_error(make_error(F, R, "LIMIT_EXCEEDED", session=robot.session_id))
        wait_until(lambda: robot.closed, 5.0, "the handler to close the robot")
        assert calls == [None, None]
        assert robot.status.errors == {"GRAPH_LIMIT": 1, "LIMIT_EXCEEDED": 1}
        with pytest.raises(RuntimeError, match="closed"):
            robot.publish([2])


def test_garbage_on_the_errors_key_is_skipped() -> None:
    bus = FakeBus()
    with bus.connect() as conn, conn.robot(F, R) as robot:
        bus.put(keys.errors(F, R), b"\x93garbage")
        bus.publish_error(make_error(F, R, "INVALID", session=robot.session_id))
        assert robot.flush_errors(5.0)
        assert robot.status.errors == {"INVALID": 1}


# -- a real service ---------------------------------------------------------------------------


def _end_session_from_outside(endpoint: str, fleet: str, robot: str, session: str) -> None:
    """Put a SessionEnd on the robot's frames key from a Zenoh session of the test's own."""
    from lessmap_client.session import open_session

    with open_session([endpoint], timeout_s=20.0) as raw:
        end = SessionEnd(session=session, last_seq=None, stamp_s=0.0)
        raw.put(keys.frames(fleet, robot), encode(end), encoding=zenoh.Encoding(encoding(end)))


@pytest.mark.parametrize("auto", [True, False], ids=["auto-new-session", "raise"])
def test_a_session_closed_by_the_service_is_noticed(
    serve: Callable[..., ServeProcess], fleet_name: str, auto: bool
) -> None:
    service = serve()
    reports: list[Error] = []
    with connect(service.endpoint, timeout_s=20.0) as conn:
        assert conn.wait_for_service(20.0), service.log()
        robot = conn.robot(fleet_name, "r1", on_error=reports.append, auto_new_session=auto)
        assert robot.wait_for_service(20.0), service.log()
        first = robot.session_id
        for seq in range(5):
            robot.publish([seq, seq + 1, 100])
        wait_until(
            lambda: (s := robot.state(1.0)) is not None and s.frames_applied == 5,
            30.0,
            "the first frames to be applied",
        )
        _end_session_from_outside(service.endpoint, fleet_name, "r1", first)
        wait_until(
            lambda: (s := robot.state(1.0)) is not None and not s.open,
            30.0,
            "the service to close the session",
        )
        robot.publish([7, 8])  # into the closed session: rejected
        wait_until(
            lambda: robot.status.closed_by_service, 30.0, "SESSION_CLOSED to reach the robot"
        )
        assert [(e.code, e.session, e.seq) for e in reports] == [
            (ErrorCode.SESSION_CLOSED, first, 5)
        ]
        if not auto:
            with pytest.raises(SessionClosedError):
                robot.publish([9])
            robot.new_session()
        for seq in range(4):
            assert robot.publish([seq, 200]) == seq
        second = robot.session_id
        assert second != first
        wait_until(
            lambda: (s := robot.state(1.0)) is not None and s.frames_applied == 4,
            30.0,
            "the new session's frames to be applied",
        )
        state = robot.state(1.0)
        assert state is not None
        assert (state.session, state.open, state.frames_missing, state.frames_rejected) == (
            second,
            True,
            0,
            0,
        )
        assert robot.status.sessions == 2
        robot.close()
        wait_until(
            lambda: (s := conn.state(fleet_name, "r1")) is not None and not s.open,
            30.0,
            "the new session to close",
        )
        closed = conn.state(fleet_name, "r1")
        assert closed is not None
        assert (closed.session, closed.frames_applied, closed.frames_missing) == (second, 4, 0)


def test_a_gap_reaches_on_error_as_seq_gap(
    serve: Callable[..., ServeProcess], fleet_name: str
) -> None:
    service = serve()
    reports: list[Error] = []
    with connect(service.endpoint, timeout_s=20.0) as conn:
        assert conn.wait_for_service(20.0), service.log()
        with conn.robot(fleet_name, "gappy", on_error=reports.append) as robot:
            assert robot.wait_for_service(20.0), service.log()
            for _ in range(10):
                robot.publish([1, 2, 3])
            assert robot.publish([3, 4], seq=20) == 20
            wait_until(lambda: bool(reports), 30.0, "the SEQ_GAP report")
            assert [(e.code, e.session, e.seq) for e in reports] == [
                (ErrorCode.SEQ_GAP, robot.session_id, 20)
            ]
            assert "10..19" in reports[0].detail
            assert robot.status.count("SEQ_GAP") == 1
            assert not robot.status.closed_by_service
            wait_until(
                lambda: (s := robot.state(1.0)) is not None and s.frames_applied == 11,
                30.0,
                "the frames to be applied",
            )
            state = robot.state(1.0)
            assert state is not None
            assert (state.frames_missing, state.last_seq) == (10, 20)
            assert robot.publish([5]) == 21  # processing goes on in the same session

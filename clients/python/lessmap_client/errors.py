"""Errors of the SDK besides ``lessmap_schemas.errors.WireError`` (a frame broke the contract)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lessmap_schemas.messages import Error


class SessionClosedError(RuntimeError):
    """The service closed the robot's session: every further frame of it would be discarded.

    Raised by ``RobotPublisher.publish`` when ``auto_new_session`` is off, or when another
    publisher holds the robot's name (starting a new session would close that one). Call
    ``robot.new_session()`` to go on under a fresh session id, numbered from 0.

    Attributes:
        fleet: fleet of the robot.
        robot: the robot.
        session_id: the session the service closed.
        error: the service's ``SESSION_CLOSED`` report.
        holder: the session the service holds open for this robot instead, if one was seen.
    """

    def __init__(
        self,
        fleet: str,
        robot: str,
        session_id: str,
        error: Error | None = None,
        holder: str | None = None,
    ) -> None:
        self.fleet = fleet
        self.robot = robot
        self.session_id = session_id
        self.error = error
        self.holder = holder
        text = f"the service closed session {session_id!r} of {fleet}/{robot}"
        if holder is not None:
            text += (
                f"; session {holder!r} is open for this robot name, from another publisher "
                "(new_session() would close it)"
            )
        else:
            text += "; call new_session() to continue (or use auto_new_session=True)"
        super().__init__(text)


class ZenohConfigError(ValueError):
    """The Zenoh configuration is invalid (a file, an endpoint) or a listen port is taken."""

"""The robot side: publish frames of one robot session to the lessmap service."""

from __future__ import annotations

import logging
import time
import uuid
from typing import TYPE_CHECKING

import zenoh

from lessmap_client.session import DEFAULT_ENDPOINT, open_session
from lessmap_client.transport import ZenohTransport, wait_for_instances
from lessmap_schemas import keys
from lessmap_schemas.codec import encode, encoding
from lessmap_schemas.errors import ErrorCode, WireError
from lessmap_schemas.limits import DEFAULT_LIMITS, WireLimits
from lessmap_schemas.messages import Frame, SessionEnd

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence
    from types import TracebackType

    from lessmap_client.transport import Host, Transport

log = logging.getLogger(__name__)

_FRAME_ENCODING = encoding(Frame)
_END_ENCODING = encoding(SessionEnd)


def new_session_id() -> str:
    """Return a fresh session id: start time plus randomness, a valid name."""
    return f"{int(time.time())}-{uuid.uuid4().hex[:12]}"


class RobotPublisher:
    """Publishes the frames of one robot session, numbered from 0.

    Declare one with ``conn.robot(fleet, robot)``. Frames go through an ``AdvancedPublisher``
    with a cache, so a service instance that takes the session over can fetch recent frames
    it missed. ``close`` ends the session explicitly (a ``SessionEnd`` with the last seq), so
    the service frees it at once.

    Args:
        fleet: fleet name (letters, digits, ``_ . -``; up to 64 characters).
        robot: robot name, same rule.
        session: the ``Connection`` to publish on, or a Zenoh session to reuse; by default a
            connection is opened to ``connect`` and closed with the publisher.
        connect: endpoints of the lessmap router (used only when ``session`` is None).
        session_id: the session id; a new random one by default (a restarted robot must
            use a new id so the service starts a new CovGraph).
        cache: frames kept for recovery by the service.
        limits: wire limits checked locally before anything is sent.
    """

    def __init__(
        self,
        fleet: str,
        robot: str,
        *,
        session: Host | zenoh.Session | None = None,
        connect: Sequence[str] = (DEFAULT_ENDPOINT,),
        session_id: str | None = None,
        cache: int = 1000,
        limits: WireLimits = DEFAULT_LIMITS,
    ) -> None:
        self.fleet = keys.validate_name(fleet, "fleet", limits)
        self.robot = keys.validate_name(robot, "robot", limits)
        self.session_id = keys.validate_name(session_id or new_session_id(), "session", limits)
        self._limits = limits
        self._key = keys.frames(self.fleet, self.robot)
        # A Connection adopts the publisher (closing it ends the session); a Zenoh session or
        # none gets a transport of the publisher's own.
        self._host: Host | None = None
        self._transport: Transport
        if isinstance(session, zenoh.Session):
            self._transport, self._owns_transport = ZenohTransport(session, owned=False), True
        elif session is None:
            opened = open_session(list(connect))
            self._transport, self._owns_transport = ZenohTransport(opened, owned=True), True
        else:
            session._check_open()
            self._host, self._transport, self._owns_transport = session, session.transport, False
        self._publisher = self._transport.publisher(self._key, _FRAME_ENCODING, cache)
        if self._host is not None:
            self._host._adopt(self)
        self._next_seq = 0
        self._closed = False

    @property
    def next_seq(self) -> int:
        """Seq the next frame will carry."""
        return self._next_seq

    @property
    def closed(self) -> bool:
        """Whether the session was ended."""
        return self._closed

    def wait_for_service(self, timeout_s: float = 10.0) -> bool:
        """Wait until a lessmap service instance is alive on the network."""
        return wait_for_instances(self._transport, timeout_s)

    def publish(
        self,
        features: Iterable[int],
        *,
        stamp_s: float | None = None,
        pose: tuple[float, float, float] | None = None,
        seq: int | None = None,
    ) -> int:
        """Publish one frame and return its seq.

        Args:
            features: IDs of the features seen together (non-negative ints < 2**63).
            stamp_s: time of the frame in seconds (default: now).
            pose: optional (x_m, y_m, theta_rad).
            seq: explicit seq (must be >= the next one; a gap is reported by the service).

        Raises:
            WireError: the frame breaks a limit or a type rule (nothing was sent).
            RuntimeError: the publisher is closed.
        """
        if self._closed:
            msg = "RobotPublisher is closed"
            raise RuntimeError(msg)
        feature_list = list(features)
        if len(feature_list) > self._limits.max_features_per_frame:
            msg = (
                f"frame has {len(feature_list)} features, over max_features_per_frame="
                f"{self._limits.max_features_per_frame}"
            )
            raise WireError(msg, code=ErrorCode.LIMIT_EXCEEDED, limit="max_features_per_frame")
        frame_seq = self._next_seq if seq is None else seq
        if frame_seq < self._next_seq:
            msg = f"seq {frame_seq} is before the next seq {self._next_seq}"
            raise WireError(msg, code=ErrorCode.OUT_OF_ORDER)
        try:
            frame = Frame(
                session=self.session_id,
                seq=frame_seq,
                stamp_s=time.time() if stamp_s is None else stamp_s,
                features=feature_list,
                pose=pose,
            )
        except ValueError as exc:
            msg = f"not a valid frame: {exc}"
            raise WireError(msg, code=ErrorCode.INVALID) from exc
        payload = encode(frame)
        if len(payload) > self._limits.max_payload_bytes:
            msg = f"frame of {len(payload)} bytes, over max_payload_bytes"
            raise WireError(msg, code=ErrorCode.LIMIT_EXCEEDED, limit="max_payload_bytes")
        self._publisher.put(payload)
        self._next_seq = frame_seq + 1
        return frame_seq

    def close(self) -> None:
        """End the session explicitly, then release the publisher (idempotent)."""
        if self._closed:
            return
        self._closed = True
        last = self._next_seq - 1 if self._next_seq else None
        end = SessionEnd(session=self.session_id, last_seq=last, stamp_s=time.time())
        try:
            # Same key as the frames: Zenoh keeps the order of puts on one key.
            self._transport.put(self._key, encode(end), _END_ENCODING)
        except Exception:  # zenoh.ZError, or a transport already closed
            log.warning("could not send the end of session %s", self.session_id)
        self._publisher.close()
        if self._host is not None:
            self._host._release(self)
        if self._owns_transport:
            self._transport.close()

    def __enter__(self) -> RobotPublisher:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

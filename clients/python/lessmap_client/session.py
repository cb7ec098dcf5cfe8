"""Open the Zenoh session a client uses: by default a client of the local lessmap router."""

from __future__ import annotations

import json
import time
from typing import TYPE_CHECKING

import zenoh

from lessmap_client.errors import ZenohConfigError
from lessmap_client.zenoh_errors import ROUTER_HINT, explain
from lessmap_schemas import keys

if TYPE_CHECKING:
    from collections.abc import Sequence

#: The embedded router of ``lessmap serve`` with no options.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def client_config(
    connect: Sequence[str] = (DEFAULT_ENDPOINT,),
    mode: str = "client",
    config_file: str | None = None,
    listen: Sequence[str] = (),
    open_timeout_s: float | None = None,
) -> zenoh.Config:
    """Return a Zenoh config that connects to ``connect`` without multicast scouting.

    ``config_file`` (JSON5, e.g. a secured site's) is the base: its endpoints stay unless
    ``connect``/``listen`` name others. ``open_timeout_s`` bounds one handshake (Zenoh's
    default is 10 s: a port held by something else than Zenoh takes that long to refuse).

    Raises:
        ZenohConfigError: the file cannot be read or an endpoint is malformed (one line).
    """
    try:
        conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if open_timeout_s is not None:
            open_timeout_ms = max(1, round(open_timeout_s * 1000))
            conf.insert_json5("transport/unicast/open_timeout", str(open_timeout_ms))
        # Explicit endpoints: scouting would only find unrelated peers on the LAN.
        conf.insert_json5("scouting/multicast/enabled", "false")
        # AdvancedPublisher's cache orders samples by timestamp; only routers stamp by default.
        conf.insert_json5("timestamping/enabled", "true")
    except zenoh.ZError as exc:
        where = f"Zenoh config {config_file}: " if config_file else ""
        msg = where + explain(str(exc), connect=connect)
        raise ZenohConfigError(msg) from exc
    return conf


def open_session(
    connect: Sequence[str] = (DEFAULT_ENDPOINT,),
    mode: str = "client",
    timeout_s: float = 10.0,
    config_file: str | None = None,
    *,
    listen: Sequence[str] = (),
    hint: str = ROUTER_HINT,
    open_timeout_s: float | None = None,
) -> zenoh.Session:
    """Open a Zenoh session for a lessmap client (the caller closes it).

    A client-mode session fails at once when no router answers yet; retry until
    ``timeout_s`` so a client started next to the service does not race it. ``hint`` is
    what the error asks the user to check when no router answers; ``open_timeout_s``
    bounds one handshake (``client_config``).

    Raises:
        ConnectionError: no router could be reached within ``timeout_s``.
        ZenohConfigError: the configuration is invalid, or a listen port is taken.
    """
    conf = client_config(connect, mode, config_file, listen, open_timeout_s)
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            text = str(exc)
            if "Unable to connect" not in text:  # not worth a retry: a port taken, ...
                raise ZenohConfigError(explain(text, connect=connect)) from exc
            if time.monotonic() >= deadline:
                msg = f"{explain(text, connect=connect, hint=hint)} (waited {timeout_s:g} s)"
                raise ConnectionError(msg) from exc
            time.sleep(0.1)


def service_instances(session: zenoh.Session, timeout_s: float = 1.0) -> list[str]:
    """Return the names of the lessmap service instances alive on the network.

    An empty answer is asked again until ``timeout_s`` has passed: a liveliness ``get``
    issued while a liveliness subscriber with history is being declared or undeclared on the
    same session (every robot publisher declares one) came back empty in 17 of 20 tries on
    zenoh 1.10 with a live token on the router, and in none 0.2 s later. So "no instance"
    takes ``timeout_s`` to say; any instance found returns at once.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = max(0.05, deadline - time.monotonic())
        found = [
            str(reply.ok.key_expr).rsplit("/", 1)[-1]
            for reply in session.liveliness().get(keys.instances(), timeout=remaining)
            if reply.ok is not None
        ]
        if found or time.monotonic() >= deadline:
            return found
        time.sleep(min(0.05, max(0.0, deadline - time.monotonic())))


def wait_for_service(session: zenoh.Session, timeout_s: float = 10.0) -> bool:
    """Wait until at least one service instance is alive; False on timeout."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if service_instances(session, timeout_s=min(1.0, max(0.1, deadline - time.monotonic()))):
            return True
        time.sleep(0.05)
    return False

"""Share a machine with another Zenoh router, such as ROS 2's ``rmw_zenohd``.

``lessmap serve`` with no Zenoh option opens its own router on ``tcp/127.0.0.1:7447``, the
port ``rmw_zenohd`` (and any Zenoh router by default) takes too. When that port is already
served by a Zenoh router, the service joins it as a *client* instead of failing: rmw_zenohd
disables peer brokering, so a client is the mode that reaches every participant. lessmap's
keys all start with ``lessmap/`` and ROS 2's with a domain id or ``@ros2_lv``, so the two
never meet on one router. A port taken by something that is not a Zenoh router is an error
that says what to do.

Before the service starts, its endpoints are checked too: a listen port already taken, or
(client mode) a router that does not answer within ``connect_timeout``, is one line that
says which flag to change, before the service has opened anything.
"""

from __future__ import annotations

import logging
import socket
from typing import TYPE_CHECKING

from lessmap.config.settings import EMBEDDED_ENDPOINT
from lessmap.errors import ConfigError

if TYPE_CHECKING:
    from lessmap.config.settings import ServiceSettings

log = logging.getLogger(__name__)


def listening(endpoint: str, timeout_s: float = 0.5) -> bool:
    """Return whether something accepts TCP connections at ``tcp/HOST:PORT``."""
    host, _, port = endpoint.removeprefix("tcp/").rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            return True
    except OSError:
        return False


def join_existing_router(
    settings: ServiceSettings, endpoint: str = EMBEDDED_ENDPOINT, timeout_s: float = 1.0
) -> ServiceSettings:
    """Return the settings to start with: a client of the router at ``endpoint`` if one is there.

    Only when no Zenoh option was given (``settings.embedded``) and ``endpoint`` is taken;
    otherwise ``settings`` unchanged, once its endpoints are checked (``check_endpoints``).

    Raises:
        ConfigError: the endpoint is taken by something that is not a Zenoh router.
    """
    if not settings.embedded:
        check_endpoints(settings)
        return settings
    if not listening(endpoint):
        return settings
    from lessmap_client.session import open_session

    try:
        open_session([endpoint], timeout_s=timeout_s, open_timeout_s=timeout_s).close()
    except ConnectionError:
        msg = (
            f"{endpoint} is taken by a program that is not a Zenoh router: stop it, or give "
            f"lessmap its own port (lessmap serve -l tcp/127.0.0.1:7448; robots and apps "
            f"then connect there with -e)"
        )
        raise ConfigError(msg) from None
    log.info(
        "a Zenoh router already listens on %s (rmw_zenohd?): joining it as a client "
        "(same as -m client -e %s; give -l to run lessmap's own router elsewhere)",
        endpoint,
        endpoint,
    )
    return settings.model_copy(update={"mode": "client", "connect": (endpoint,)})


def check_endpoints(settings: ServiceSettings) -> None:
    """Check the Zenoh endpoints the flags name, before the service opens anything.

    The Zenoh config file must exist. A TCP listen port that something already accepts on
    is taken. In client mode the service needs a router: wait for one up to
    ``connect_timeout`` seconds.

    Raises:
        ConfigError: the file is missing, a listen port is taken, or no router answered.
    """
    if settings.zenoh_config is not None and not settings.zenoh_config.is_file():
        msg = f"-c/--zenoh-config {settings.zenoh_config}: no such file"
        raise ConfigError(msg)
    for endpoint in settings.listen:
        if endpoint.startswith("tcp/") and listening(endpoint):
            msg = (
                f"cannot listen on {endpoint}: the port is already in use; stop the program "
                "that holds it or choose another port with -l/--listen"
            )
            raise ConfigError(msg)
    if settings.mode == "client" and (settings.connect or settings.zenoh_config is not None):
        from lessmap_client.session import open_session

        config = None if settings.zenoh_config is None else str(settings.zenoh_config)
        try:
            open_session(
                settings.connect, timeout_s=settings.connect_timeout, config_file=config
            ).close()
        except (ConnectionError, ValueError) as exc:
            raise ConfigError(str(exc)) from None

"""``lessmap router``: a plain Zenoh router in this process, for several service instances.

No lessmap service runs in it: it only routes, like ``zenohd`` (which has no Python package).
Service instances (``lessmap serve -m client -e ...``), robots and fleet apps connect to it;
routers connect to each other with ``-e`` to form a mesh. The Zenoh config is built by the
service's own code (``zenoh_config.service_config``) in router mode; then two defaults of
this command apply where neither the flags nor the file say otherwise: listen on
``tcp/127.0.0.1:7447`` only, and no multicast scouting.
"""

from __future__ import annotations

import json
import logging
import re
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from lessmap.config.settings import EMBEDDED_ENDPOINT, ServiceSettings
from lessmap.errors import ConfigError
from lessmap.runtime.supervisor import SignalEvent
from lessmap.runtime.zenoh_config import service_config

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence
    from types import FrameType

log = logging.getLogger(__name__)

#: Where the router listens when neither ``-l`` nor the config file names an endpoint.
DEFAULT_LISTEN = EMBEDDED_ENDPOINT

# Zenoh's error texts end with the Rust source location of the error: not for the user.
_SOURCE_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?")


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap router`` until a stop signal; return 0 (1 is a ``ConfigError``)."""
    # The CLI logs only warnings for commands other than serve; a daemon reports its start.
    if log.getEffectiveLevel() > logging.INFO:
        log.setLevel(logging.INFO)
    conf = router_config(args.config, args.listen, args.connect, args.cfg)
    zenoh.init_log_from_env_or("error")
    stop = SignalEvent()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s", signal.Signals(signum).name)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            msg = f"Zenoh could not start the router: {_clean(exc)}"
            raise ConfigError(msg) from exc
        try:
            connect = _endpoints(conf, "connect/endpoints")
            log.info(
                "router listening on %s%s (zid %s)",
                ", ".join(_endpoints(conf, "listen/endpoints")),
                f", connecting to {', '.join(connect)}" if connect else "",
                session.info.zid(),
            )
            # Park on an Event: signals are handled between waits.
            while not stop.wait(0.5):
                pass
        finally:
            session.close()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    log.info("router stopped")
    return 0


def router_config(
    config_file: Path | None,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    extra: Sequence[str] = (),
) -> zenoh.Config:
    """Return the router's Zenoh config: the file, the flags, then this command's defaults.

    Raises:
        ConfigError: the file is missing or invalid, or an override is.
    """
    if config_file is not None and not config_file.is_file():
        msg = f"Zenoh config {config_file}: no such file"
        raise ConfigError(msg)
    # The same builder as `lessmap serve`, in router mode: only its Zenoh fields are read,
    # so the settings are not validated or read from the environment here.
    settings = ServiceSettings.model_construct(
        zenoh_config=config_file, mode="router", listen=tuple(listen), connect=tuple(connect)
    )
    try:
        conf = service_config(settings, extra)
    except ConfigError as exc:
        raise ConfigError(_clean(exc)) from exc
    try:
        if conf.get_json("listen/endpoints") == zenoh.Config().get_json("listen/endpoints"):
            # Neither flag nor file chose: loopback, never Zenoh's default of every interface.
            conf.insert_json5("listen/endpoints", json.dumps([DEFAULT_LISTEN]))
        if json.loads(conf.get_json("scouting/multicast/enabled")) is None:
            conf.insert_json5("scouting/multicast/enabled", "false")
    except zenoh.ZError as exc:  # pragma: no cover - keys known to exist
        msg = f"invalid Zenoh configuration: {_clean(exc)}"
        raise ConfigError(msg) from exc
    return conf


def _endpoints(conf: zenoh.Config, key: str) -> list[str]:
    value: Any = json.loads(conf.get_json(key))
    if isinstance(value, dict):  # a mode-dependent list
        value = value.get("router", [])
    return [str(v) for v in value or []]


def _clean(exc: BaseException) -> str:
    return " ".join(_SOURCE_LOCATION.sub("", str(exc)).split())

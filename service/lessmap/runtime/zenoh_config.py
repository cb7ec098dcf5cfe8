"""Build the Zenoh configuration of the service from its settings.

Zenoh's own configuration is never re-modelled: a JSON5 file goes to
``zenoh.Config.from_file``; ``--mode``, ``--connect``, ``--listen`` and ``--cfg KEY:VALUE``
override it, spelled as in zenoh-python's examples.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import zenoh

from lessmap.config.qos import WAIT_BEFORE_DROP_US, slow_consumer_qos
from lessmap.config.settings import EMBEDDED_ENDPOINT
from lessmap.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.config.settings import ServiceSettings


def service_config(settings: ServiceSettings, extra: Sequence[str] = ()) -> zenoh.Config:
    """Return the Zenoh config: an embedded loopback router unless told otherwise.

    Args:
        settings: the service settings (mode, connect, listen, zenoh_config).
        extra: ``KEY:VALUE`` overrides (VALUE is JSON5), applied last.

    Raises:
        ConfigError: the file cannot be read or an override is invalid.
    """
    try:
        if settings.zenoh_config is not None:
            conf = zenoh.Config.from_file(str(settings.zenoh_config))
        else:
            conf = zenoh.Config()
        if settings.embedded:
            # One machine, nothing else to run: be the router, on loopback only, and don't
            # go looking for other routers on the LAN.
            conf.insert_json5("mode", json.dumps("router"))
            conf.insert_json5("listen/endpoints", json.dumps([EMBEDDED_ENDPOINT]))
            conf.insert_json5("scouting/multicast/enabled", "false")
        if settings.mode is not None:
            conf.insert_json5("mode", json.dumps(settings.mode))
        if settings.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
        if settings.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
        # The transitions' AdvancedPublisher cache needs timestamps in every mode.
        conf.insert_json5("timestamping/enabled", "true")
        for item in extra:
            key, sep, value = item.partition(":")
            if not sep:
                msg = f"--cfg expects KEY:VALUE, got {item!r}"
                raise ConfigError(msg)
            conf.insert_json5(key, value)
        _safe_defaults(conf)
    except zenoh.ZError as exc:
        msg = f"invalid Zenoh configuration: {exc}"
        raise ConfigError(msg) from exc
    return conf


# Zenoh's own defaults where neither a flag, the file nor --cfg chose: the values a config
# leaves at null (mode-dependent) or at Zenoh's built-in listen endpoints.
_ZENOH_DEFAULT_LISTEN = zenoh.Config().get_json("listen/endpoints")
_LOOPBACK_LISTEN = {"router": "tcp/127.0.0.1:7447", "peer": "tcp/127.0.0.1:0"}


_WAIT_BEFORE_DROP = "transport/link/tx/queue/congestion_control/drop/wait_before_drop"
_ZENOH_WAIT_BEFORE_DROP_US = 1000


def _safe_defaults(conf: zenoh.Config) -> None:
    """No multicast scouting, loopback listening, drop toward slow consumers, unless asked.

    Zenoh's defaults suit a LAN of trusted peers: multicast scouting on, and peers and routers
    listening on every interface. A service that joins a site names its endpoints instead
    (``-e``/``-l`` or its config file); what it did not name stays on this machine.
    """
    if not json.loads(conf.get_json("qos/network")):
        conf.insert_json5("qos/network", json.dumps(slow_consumer_qos()))
    if json.loads(conf.get_json(_WAIT_BEFORE_DROP)) == _ZENOH_WAIT_BEFORE_DROP_US:
        conf.insert_json5(_WAIT_BEFORE_DROP, str(WAIT_BEFORE_DROP_US))
    if json.loads(conf.get_json("scouting/multicast/enabled")) is None:
        conf.insert_json5("scouting/multicast/enabled", "false")
    if conf.get_json("listen/endpoints") == _ZENOH_DEFAULT_LISTEN:
        mode = json.loads(conf.get_json("mode")) or "peer"
        if mode in _LOOPBACK_LISTEN:
            conf.insert_json5("listen/endpoints", json.dumps([_LOOPBACK_LISTEN[mode]]))

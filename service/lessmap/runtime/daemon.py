"""Run the service in the foreground until SIGTERM or SIGINT (systemd-friendly)."""

from __future__ import annotations

import logging
import signal
import threading
from typing import TYPE_CHECKING, Any

import zenoh
from threadpoolctl import threadpool_limits

from lessmap.errors import ConfigError
from lessmap.runtime.service import Service
from lessmap.settings import add_settings_flags, settings_from_args

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence
    from types import FrameType

    from lessmap.flags import FlagSpec
    from lessmap.settings import ServiceSettings

log = logging.getLogger(__name__)


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap serve``: one flag per settings field, plus --shard I/N and --cfg."""
    parser.description = (
        "Run the partition service in the foreground until SIGTERM/SIGINT. With no Zenoh "
        "option it opens its own router on tcp/127.0.0.1:7447. Settings come from defaults "
        "< --config FILE (JSON or TOML) < LESSMAP_* environment < these flags."
    )
    specs = add_settings_flags(parser)
    parser.add_argument(
        "--shard",
        metavar="I/N",
        help="serve only the robots whose key hashes to I of N (sets --shard-index and "
        "--shard-count; run one instance per I)",
    )
    parser.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="Zenoh config override, VALUE in JSON5 (repeatable)",
    )
    parser.set_defaults(settings_flags=specs)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap serve`` with the settings its flags, environment and file give."""
    specs: list[FlagSpec] = args.settings_flags
    shard = shard_values(args.shard)
    settings = settings_from_args(args, specs, shard, dict.fromkeys(shard, "--shard"))
    return serve(settings, args.cfg or ())


def shard_values(text: str | None) -> dict[str, Any]:
    """Parse ``--shard I/N`` into the two settings.

    Raises:
        ConfigError: the text is not two integers separated by a slash.
    """
    if text is None:
        return {}
    index, sep, count = text.partition("/")
    if not sep or not index.isdigit() or not count.isdigit():
        msg = f"--shard expects I/N, e.g. 0/2, got {text!r}"
        raise ConfigError(msg)
    return {"shard_index": int(index), "shard_count": int(count)}


def serve(settings: ServiceSettings, zenoh_cfg: Sequence[str] = ()) -> int:
    """Start the service, park the main thread until a stop signal, stop cleanly.

    Returns:
        0 after a clean shutdown.

    Raises:
        ConfigError: the service could not start (the CLI prints one line).
    """
    # Each shard decides on its own thread; a multi-threaded BLAS under every one of them
    # oversubscribes the cores (a dense eigh went from 0.13 s to 7.9 s under load).
    with threadpool_limits(limits=1):
        return _serve(settings, zenoh_cfg)


def _serve(settings: ServiceSettings, zenoh_cfg: Sequence[str]) -> int:
    zenoh.init_log_from_env_or("error")
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s", signal.Signals(signum).name)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    service = Service(settings, zenoh_cfg)
    try:
        service.start()
        # Park on an Event, not on a Zenoh receive: signals are handled between waits.
        while not stop.wait(0.5):
            pass
    finally:
        service.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0

"""``serve --workers N`` in the parent: the workers' router, their stores, then the supervisor.

Where the workers meet: unless the settings make the service a Zenoh client, the parent
opens the Zenoh router a single instance would have been (the embedded one on
``tcp/127.0.0.1:7447``, or the ``-l``/``-c`` endpoints, with the same overrides), and the
workers are its clients over loopback. A worker that dies leaves the router, the robots'
links and the other workers untouched. In client mode every worker joins the named routers.

Before any worker starts, the checkpoints held in the workers' state directories are
gathered into worker 0's (newest record per robot): worker 0 starts alone and takes every
partition, so it must resume every session; the others then take theirs from it.
"""

from __future__ import annotations

import json
import logging
import shutil
import signal
import socket
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh

from lessmap.errors import ConfigError
from lessmap.runtime.store import STORE_FILE, CheckpointStore, StoreError
from lessmap.runtime.supervisor import LaunchSpec, RestartPolicy, SignalEvent, Supervisor
from lessmap.runtime.workers import worker_count, worker_settings, worker_state_dir
from lessmap.runtime.zenoh_config import service_config

if TYPE_CHECKING:
    from collections.abc import Sequence
    from types import FrameType

    from lessmap.config.settings import ServiceSettings

log = logging.getLogger(__name__)

_MAX_PORT = 65535


def serve_workers(
    settings: ServiceSettings,
    zenoh_cfg: Sequence[str] = (),
    *,
    verbose: int = 0,
    log_format: str = "text",
    policy: RestartPolicy | None = None,
) -> int:
    """Run ``worker_count(settings)`` workers until SIGTERM or SIGINT; return the exit code.

    Raises:
        ConfigError: the router could not open, or a state directory is in use.
    """
    count = worker_count(settings)
    port = settings.metrics_port
    if port and port + count - 1 > _MAX_PORT:
        msg = f"--metrics-port {port}: {count} workers need ports up to {port + count - 1}"
        raise ConfigError(msg)
    if not settings.memory_only:
        gather_checkpoints(settings, count)
    hub = hub_config(settings, zenoh_cfg)
    stop = SignalEvent()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s: stopping the workers", signal.Signals(signum).name)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    router: zenoh.Session | None = None
    folder = Path(tempfile.mkdtemp(prefix="lessmap-workers-"))
    try:
        if hub is not None:
            router = _open(hub[0], settings)
        endpoint = None if hub is None else hub[1]
        supervisor = Supervisor(
            [worker_settings(settings, i, endpoint) for i in range(count)],
            LaunchSpec(
                folder,
                verbose=verbose,
                log_format=log_format,
                zenoh_cfg=() if hub is not None else tuple(zenoh_cfg),
            ),
            policy,
        )
        log.info(
            "lessmap serve: %d workers (%s-w0 ... -w%d)%s",
            count,
            settings.instance,
            count - 1,
            f", their router on {endpoint}" if endpoint else ", each a client of the routers",
        )
        healthy = False
        try:
            healthy = supervisor.start(stop) and supervisor.watch(stop)
        finally:
            clean = supervisor.stop()
        log.info("all workers stopped")
        return 0 if (healthy or stop.is_set()) and clean else 1
    finally:
        if router is not None:
            router.close()
        shutil.rmtree(folder, ignore_errors=True)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def hub_config(
    settings: ServiceSettings, zenoh_cfg: Sequence[str]
) -> tuple[zenoh.Config, str] | None:
    """The parent's router config and the loopback endpoint its workers connect to.

    None in client mode: the workers join the routers themselves. A peer becomes a router
    (it routes for its workers). The workers use a ``tcp/127.0.0.1`` endpoint the router
    listens on, else one added on a free port.

    Raises:
        ConfigError: the Zenoh configuration is invalid.
    """
    conf = service_config(settings, zenoh_cfg)
    mode = json.loads(conf.get_json("mode")) or "peer"
    if mode == "client":
        return None
    listen = _endpoints(conf.get_json("listen/endpoints"))
    loopback = [e for e in listen if e.startswith("tcp/127.0.0.1:") and not e.endswith(":0")]
    if loopback:
        endpoint = loopback[0]
    else:
        endpoint = f"tcp/127.0.0.1:{_free_port()}"
        conf.insert_json5("listen/endpoints", json.dumps([*listen, endpoint]))
    conf.insert_json5("mode", json.dumps("router"))
    return conf, endpoint


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


def _endpoints(text: str) -> list[str]:
    value = json.loads(text)
    if isinstance(value, dict):  # a mode-dependent list
        value = value.get("router", [])
    return [str(v) for v in value or []]


def _open(conf: zenoh.Config, settings: ServiceSettings) -> zenoh.Session:
    zenoh.init_log_from_env_or("error")
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        where = "tcp/127.0.0.1:7447" if settings.embedded else ", ".join(settings.listen)
        msg = f"Zenoh could not start the workers' router on {where or 'its endpoints'}: {exc}"
        raise ConfigError(msg) from exc


def gather_checkpoints(settings: ServiceSettings, count: int) -> int:
    """Copy every worker store's records into worker 0's where newer; return how many.

    Worker folders beyond ``count`` (a previous run with more workers) are read too.

    Raises:
        ConfigError: a state directory is in use by a running instance, or unusable.
    """
    base = settings.resolved_state_dir()
    others = [worker_state_dir(base, i) for i in range(1, count)]
    others += sorted(
        p.parent
        for p in base.glob("w*/" + STORE_FILE)
        if p.parent.name[1:].isdigit() and p.parent not in others
    )
    others = [p for p in others if (p / STORE_FILE).is_file()]
    if not others:
        return 0
    target = _store(base, settings)
    taken = 0
    try:
        for folder in others:
            source = _store(folder, settings)
            try:
                taken += sum(target.offer(record) for record in source.records())
            finally:
                source.close()
    finally:
        target.close()
    log.info(
        "gathered %d newer checkpoint(s) from %d worker store(s) into %s", taken, len(others), base
    )
    return taken


def _store(folder: Path, settings: ServiceSettings) -> CheckpointStore:
    store = CheckpointStore(
        folder, retention_s=settings.state_retention_s, max_bytes=settings.state_max_bytes
    )
    try:
        store.open()
    except StoreError as exc:
        msg = str(exc)
        raise ConfigError(msg) from exc
    return store

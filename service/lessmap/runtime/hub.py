"""``serve --workers N`` in the parent: the workers' router, their stores, then the supervisor.

Where the workers meet: unless the settings make the service a Zenoh client, the parent
opens the Zenoh router a single instance would have been (the embedded one on
``tcp/127.0.0.1:7447``, or the ``-l``/``-c`` endpoints, with the same overrides), and the
workers are its clients over a Unix socket in the parent's private folder: only this OS
user can open it, so a secured site's router gains no unauthenticated way in. Its access
control gets one subject more, the workers' link protocol; with user/password
authentication the workers present the configuration's own user. (A TCP loopback endpoint
where Unix sockets are missing.) A worker that dies leaves the router, the robots' links
and the other workers untouched. In client mode every worker joins the named routers.

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
from typing import TYPE_CHECKING, NamedTuple

import zenoh

from lessmap.errors import ConfigError
from lessmap.runtime.store import STORE_FILE, CheckpointStore, StoreError
from lessmap.runtime.supervisor import LaunchSpec, RestartPolicy, SignalEvent, Supervisor
from lessmap.runtime.workers import worker_count, worker_settings, worker_state_dir
from lessmap.runtime.zenoh_config import service_config
from lessmap.security.siteconfig import workers_access

if TYPE_CHECKING:
    from collections.abc import Sequence
    from types import FrameType

    from lessmap.config.settings import ServiceSettings

log = logging.getLogger(__name__)

_MAX_PORT = 65535
#: Unix socket paths are limited to ~108 bytes; a longer private folder is not used.
_MAX_SOCKET_PATH = 100


class Hub(NamedTuple):
    """The parent's router config, where its workers connect, and their Zenoh overrides."""

    config: zenoh.Config
    endpoint: str
    worker_cfg: tuple[str, ...]  # ``--cfg`` overrides, carried in the private worker files


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
    folder = Path(tempfile.mkdtemp(prefix="lessmap-workers-"))  # this user's only (0700)
    try:
        hub = hub_config(settings, zenoh_cfg, folder)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    stop = SignalEvent()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s: stopping the workers", signal.Signals(signum).name)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    router: zenoh.Session | None = None
    try:
        if hub is not None:
            router = _open(hub.config, settings)
        endpoint = None if hub is None else hub.endpoint
        supervisor = Supervisor(
            [worker_settings(settings, i, endpoint) for i in range(count)],
            LaunchSpec(
                folder,
                verbose=verbose,
                log_format=log_format,
                zenoh_cfg=hub.worker_cfg if hub is not None else tuple(zenoh_cfg),
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
    settings: ServiceSettings, zenoh_cfg: Sequence[str], folder: Path | None = None
) -> Hub | None:
    """The parent's router config, where its workers connect, and their overrides.

    None in client mode: the workers join the routers themselves. A peer becomes a router
    (it routes for its workers). The workers connect to a Unix socket in ``folder`` (a
    private folder); without one, or without Unix sockets, to a ``tcp/127.0.0.1`` endpoint
    the router listens on, else one added on a free port.

    Raises:
        ConfigError: the Zenoh configuration is invalid.
    """
    conf = service_config(settings, zenoh_cfg)
    mode = json.loads(conf.get_json("mode")) or "peer"
    if mode == "client":
        return None
    listen = _endpoints(conf.get_json("listen/endpoints"))
    conf.insert_json5("mode", json.dumps("router"))
    worker_cfg = _credentials(conf)
    socket_path = "" if folder is None else str(folder / "hub.sock")
    if socket_path and hasattr(socket, "AF_UNIX") and len(socket_path) <= _MAX_SOCKET_PATH:
        endpoint = f"unixsock-stream/{socket_path}"
        conf.insert_json5("listen/endpoints", json.dumps([*listen, endpoint]))
        _allow_workers(conf)
        return Hub(conf, endpoint, worker_cfg)
    loopback = [e for e in listen if e.startswith("tcp/127.0.0.1:") and not e.endswith(":0")]
    if loopback:
        endpoint = loopback[0]
    else:
        endpoint = f"tcp/127.0.0.1:{_free_port()}"
        conf.insert_json5("listen/endpoints", json.dumps([*listen, endpoint]))
    return Hub(conf, endpoint, worker_cfg)


def _allow_workers(conf: zenoh.Config) -> None:
    """Give the workers' socket link everything, where access control is on."""
    access = json.loads(conf.get_json("access_control"))
    if not access.get("enabled"):
        return
    workers = workers_access()
    for part, entry in (("subjects", "subject"), ("rules", "rule"), ("policies", "policy")):
        access[part] = [*(access.get(part) or []), workers[entry]]
    conf.insert_json5("access_control", json.dumps(access))


def _credentials(conf: zenoh.Config) -> tuple[str, ...]:
    """The configuration's own user and password, for workers of a user/password site.

    Raises:
        ConfigError: the router checks users but has none of its own to give.
    """
    usrpwd = json.loads(conf.get_json("transport/auth/usrpwd"))
    user, password = usrpwd.get("user"), usrpwd.get("password")
    if not (user and password):
        if usrpwd.get("dictionary_file"):
            msg = (
                "this router authenticates users (transport/auth/usrpwd/dictionary_file), so "
                "its workers need the configuration's own user and password (one of the "
                "dictionary's); give them, or run --workers 1, or -m client"
            )
            raise ConfigError(msg)
        return ()
    return (
        f"transport/auth/usrpwd/user:{json.dumps(user)}",
        f"transport/auth/usrpwd/password:{json.dumps(password)}",
    )


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

"""One ``serve`` on every core: what each worker process is, and its side of the supervision.

A worker is an ordinary instance (its own name, state directory, metrics port) started by
the ``serve --workers N`` parent (``supervisor.py``). The parent hands it a worker file
(JSON: its index, the parent's PID, the pipe to say it is ready, its whole settings) and
nothing else: environment variables and flags were already read by the parent.

Rules of this file:

1. Worker ``i`` of instance ``base`` is named ``base-w<i>``; worker 0 keeps the state
   directory itself (a single instance's store stays readable), worker ``i`` uses ``w<i>``.
2. A worker dies with its parent: ``PR_SET_PDEATHSIG`` (Linux) sends it SIGTERM, and a
   worker whose parent is already gone when it starts does not start.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import signal
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from lessmap.config.settings import ServiceSettings
from lessmap.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

_PR_SET_PDEATHSIG = 1  # linux/prctl.h
_MAX_NAME_LEN = 64


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def worker_count(settings: ServiceSettings) -> int:
    """How many worker processes ``serve`` runs: the setting, else the usable cores."""
    return settings.workers if settings.workers is not None else usable_cores()


def worker_name(instance: str, index: int) -> str:
    """Worker ``index``'s instance name: ``<instance>-w<index>``, cut to the name limit."""
    suffix = f"-w{index}"
    return instance[: _MAX_NAME_LEN - len(suffix)] + suffix


def worker_state_dir(state_dir: Path, index: int) -> Path:
    """Worker ``index``'s state directory (rule 1)."""
    return state_dir if index == 0 else state_dir / f"w{index}"


def worker_settings(settings: ServiceSettings, index: int, hub: str | None) -> ServiceSettings:
    """The settings of worker ``index``: its name, store and metrics port; the hub's client.

    Args:
        settings: the service's settings, as the parent read them.
        index: the worker's index, from 0.
        hub: the loopback endpoint of the parent's router, or None when every worker joins
            the network the settings name by itself (client mode).
    """
    port = settings.metrics_port
    update: dict[str, Any] = {
        "workers": 1,
        "instance": worker_name(settings.instance, index),
        "state_dir": worker_state_dir(settings.resolved_state_dir(), index),
        "metrics_port": port + index if port else port,  # 0: each its own free port
        "config": None,
    }
    if hub is not None:
        update |= {"mode": "client", "connect": (hub,), "listen": (), "zenoh_config": None}
    return settings.model_copy(update=update)


@dataclass(frozen=True, slots=True)
class WorkerRole:
    """What a worker process is told by its parent, besides its settings."""

    index: int
    parent_pid: int
    ready_fd: int

    @property
    def tag(self) -> str:
        """How its log lines name it: ``w<index>``."""
        return f"w{self.index}"


def write_worker_file(
    path: Path, role: WorkerRole, settings: ServiceSettings, zenoh_cfg: Sequence[str]
) -> None:
    """Write what worker ``role.index`` needs to start (readable by its owner only)."""
    body = {
        "role": {"index": role.index, "parent_pid": role.parent_pid, "ready_fd": role.ready_fd},
        "settings": settings.model_dump(mode="json"),
        "zenoh_cfg": list(zenoh_cfg),
    }
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
        json.dump(body, handle)


def read_worker_file(path: Path) -> tuple[WorkerRole, ServiceSettings, list[str]]:
    """Return a worker's role, settings and Zenoh overrides from its worker file.

    Raises:
        ConfigError: the file cannot be read or is not a worker file.
    """
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
        role = WorkerRole(**body["role"])
        # Every field is given, so neither the environment nor a config file adds anything.
        settings = ServiceSettings(**body["settings"])
        zenoh_cfg = [str(item) for item in body["zenoh_cfg"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        msg = f"worker file {path}: {exc}"
        raise ConfigError(msg) from exc
    return role, settings, zenoh_cfg


def die_with_parent(parent_pid: int) -> bool:
    """Ask the kernel for SIGTERM when the parent dies; False when it is already gone.

    The request survives ``exec`` (the allocator restart of ``serve``). Without
    ``prctl`` (not Linux) only the start-up check is made.
    """
    path = ctypes.util.find_library("c")
    if path is not None:
        prctl = getattr(ctypes.CDLL(path, use_errno=True), "prctl", None)
        if prctl is not None:
            prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    # Checked after the request: a parent that died before it would never signal.
    return os.getppid() == parent_pid


def signal_ready(role: WorkerRole) -> None:
    """Tell the parent this worker serves (one byte on its pipe; a gone parent is ignored)."""
    try:
        os.write(role.ready_fd, b"1")
        os.close(role.ready_fd)
    except OSError:
        pass

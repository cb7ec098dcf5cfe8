"""The parent of ``serve --workers N``: start the worker processes, restart them, stop them.

Each worker is ``python -m lessmap serve --worker-file F``, an ordinary instance.

Invariants:

1. Workers start one after the other, each once the previous one serves: every join is a
   hand-over from running instances, never a race of instances that each think they are
   alone.
2. A worker that dies is started again after a back-off (doubling); meanwhile the others
   take its partitions over. More than ``max_restarts`` deaths of one worker within
   ``window_s`` stop the whole service.
3. Every worker has a process group of its own (a terminal's Ctrl-C reaches the parent
   only), dies with the parent, and is stopped, or killed after ``stop_timeout_s``, by PID.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lessmap.runtime.workers import WorkerRole, write_worker_file

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from lessmap.config.settings import ServiceSettings

log = logging.getLogger(__name__)

_TICK_S = 0.1


@dataclass(frozen=True, slots=True, kw_only=True)
class RestartPolicy:
    """How the parent starts, restarts and stops its workers."""

    # The worker's return moves its partitions a second time, by hand-over: sessions still
    # waiting for a catch-up at the survivor then need the robots' caches again. Long enough
    # for the take-over and a catch-up (catchup_wait_s, 2 s) to end first.
    first_backoff_s: float = 5.0
    max_backoff_s: float = 30.0
    max_restarts: int = 5  # deaths of one worker within window_s before the service stops
    window_s: float = 300.0
    ready_timeout_s: float = 120.0  # a worker's start, from launch to serving
    stop_timeout_s: float = 30.0  # after SIGTERM, before SIGKILL


@dataclass(frozen=True, slots=True)
class LaunchSpec:
    """What every worker's command line shares: the logging options and a private folder."""

    folder: Path  # worker files, readable by this user only
    verbose: int = 0
    log_format: str = "text"
    zenoh_cfg: tuple[str, ...] = ()


@dataclass(slots=True)
class WorkerSlot:
    """One worker index: its current process (if any) and its restart history."""

    index: int
    settings: ServiceSettings
    process: subprocess.Popen[bytes] | None = None
    ready_fd: int | None = None  # read end of the process's ready pipe
    serving: bool = False
    due_s: float | None = None  # when a dead worker is started again
    deaths: deque[float] = field(default_factory=deque)

    @property
    def tag(self) -> str:
        """``w<index>``."""
        return f"w{self.index}"


class SignalEvent(threading.Event):
    """An Event that a signal handler may set.

    ``Event.set`` takes the event's lock; a handler runs on the main thread, which may hold
    that very lock inside ``Event.wait``, and then blocks forever (seen after a worker's
    parent died: three SIGTERMs logged, the worker never stopped). Here ``set`` only writes
    a flag, and ``wait`` polls it in short sleeps.
    """

    def __init__(self) -> None:
        super().__init__()
        self._signalled = False

    def set(self) -> None:
        """Mark the event set; takes no lock."""
        self._signalled = True

    def is_set(self) -> bool:
        """True once set."""
        return self._signalled

    def wait(self, timeout: float | None = None) -> bool:
        """True once set, False after ``timeout`` seconds (None: no limit)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._signalled:
            left = 0.05 if deadline is None else min(0.05, deadline - time.monotonic())
            if left <= 0:
                return False
            time.sleep(left)
        return True


class Supervisor:
    """Runs the workers of one ``serve``; every method is called from the main thread."""

    def __init__(
        self,
        settings: Sequence[ServiceSettings],
        launch: LaunchSpec,
        policy: RestartPolicy | None = None,
    ) -> None:
        self.slots = [WorkerSlot(i, s) for i, s in enumerate(settings)]
        self.launch = launch
        self.policy = policy or RestartPolicy()

    def start(self, stop: threading.Event) -> bool:
        """Start every worker in turn (invariant 1); False when one failed or ``stop`` was set."""
        for slot in self.slots:
            self._spawn(slot)
            deadline = time.monotonic() + self.policy.ready_timeout_s
            while not self._check_ready(slot):
                assert slot.process is not None
                if slot.process.poll() is not None:
                    log.error(
                        "worker %s %s before it served: stopping",
                        slot.tag,
                        describe_exit(slot.process.returncode),
                    )
                    return False
                if stop.wait(_TICK_S):
                    return False
                if time.monotonic() > deadline:
                    log.warning(
                        "worker %s does not serve after %.0f s: starting the next one",
                        slot.tag,
                        self.policy.ready_timeout_s,
                    )
                    break
        return True

    def watch(self, stop: threading.Event) -> bool:
        """Restart workers that die until ``stop`` is set; False when one died too often."""
        while not stop.wait(_TICK_S):
            now = time.monotonic()
            for slot in self.slots:
                died = slot.process is not None and slot.process.poll() is not None
                if died and not self._schedule_restart(slot, now):
                    return False
                if slot.process is None and slot.due_s is not None and now >= slot.due_s:
                    slot.due_s = None
                    self._spawn(slot)
                if slot.process is not None and not slot.serving and self._check_ready(slot):
                    log.info("worker %s (pid %d) serves", slot.tag, slot.process.pid)
        return True

    def stop(self) -> bool:
        """SIGTERM every worker, wait, SIGKILL what is left; True when all stopped by themselves."""
        for slot in self.slots:
            if slot.process is not None and slot.process.poll() is None:
                slot.process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + self.policy.stop_timeout_s
        clean = True
        for slot in self.slots:
            process = slot.process
            if process is None:
                continue
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning(
                    "worker %s (pid %d) still runs %.0f s after SIGTERM: killed",
                    slot.tag,
                    process.pid,
                    self.policy.stop_timeout_s,
                )
                process.kill()
                process.wait()
                clean = False
            self._close_ready(slot)
            slot.process = None
        return clean

    # -- one worker ------------------------------------------------------------------------------

    def _spawn(self, slot: WorkerSlot) -> None:
        read_fd, write_fd = os.pipe()
        os.set_blocking(read_fd, False)
        role = WorkerRole(slot.index, os.getpid(), write_fd)
        path = self.launch.folder / f"{slot.tag}.json"
        write_worker_file(path, role, slot.settings, self.launch.zenoh_cfg)
        command = [sys.executable, "-m", "lessmap", *["-v"] * self.launch.verbose]
        command += ["--log-format", self.launch.log_format, "serve", "--worker-file", str(path)]
        try:
            # Its own process group: a terminal's SIGINT is the parent's to pass on.
            slot.process = subprocess.Popen(command, pass_fds=(write_fd,), process_group=0)
        finally:
            os.close(write_fd)
        slot.ready_fd = read_fd
        slot.serving = False
        log.info(
            "worker %s started as %s (pid %d)", slot.tag, slot.settings.instance, slot.process.pid
        )

    def _check_ready(self, slot: WorkerSlot) -> bool:
        if slot.ready_fd is None:
            return slot.serving
        try:
            said = os.read(slot.ready_fd, 1)
        except BlockingIOError:
            return False
        self._close_ready(slot)
        slot.serving = bool(said)  # b"": the worker closed the pipe without serving
        return slot.serving

    def _close_ready(self, slot: WorkerSlot) -> None:
        if slot.ready_fd is not None:
            os.close(slot.ready_fd)
            slot.ready_fd = None

    def _schedule_restart(self, slot: WorkerSlot, now: float) -> bool:
        """Note a death and when to start the worker again; False past the restart budget."""
        assert slot.process is not None
        policy = self.policy
        how = describe_exit(slot.process.returncode)
        pid = slot.process.pid
        self._close_ready(slot)
        slot.process = None
        slot.serving = False
        while slot.deaths and now - slot.deaths[0] > policy.window_s:
            slot.deaths.popleft()
        slot.deaths.append(now)
        if len(slot.deaths) > policy.max_restarts:
            log.error(
                "worker %s (pid %d) %s: its %d deaths within %.0f s exceed the %d restarts "
                "allowed; stopping the service",
                slot.tag,
                pid,
                how,
                len(slot.deaths),
                policy.window_s,
                policy.max_restarts,
            )
            return False
        delay_s = min(policy.max_backoff_s, policy.first_backoff_s * 2 ** (len(slot.deaths) - 1))
        slot.due_s = now + delay_s
        log.warning(
            "worker %s (pid %d) %s; the other workers take its partitions over; restart %d "
            "of %d allowed within %.0f s in %.1f s",
            slot.tag,
            pid,
            how,
            len(slot.deaths),
            policy.max_restarts,
            policy.window_s,
            delay_s,
        )
        return True


def describe_exit(returncode: int) -> str:
    """'exited with code 1' or 'was killed by SIGKILL'."""
    if returncode < 0:
        try:
            return f"was killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"was killed by signal {-returncode}"
    return f"exited with code {returncode}"

"""An actor's inbox: commands for one worker thread, answered through futures.

Invariants:

1. While the worker runs, a command runs on the worker, in the order sent, when the worker
   takes its inbox (``run_pending``); the sender waits on the ``Future`` it got back.
2. Once the worker has finished (``finish``), a command runs on the sender's thread, one at
   a time: the state it touches still has a single user.
3. A command's error reaches its sender through the future, and the log.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger(__name__)

T = TypeVar("T")


class CommandInbox:
    """Commands for one worker; ``wake`` is the worker's condition (notified on a send)."""

    def __init__(self, wake: threading.Condition) -> None:
        self._wake = wake
        self._commands: deque[tuple[Callable[[], Any], Future[Any]]] = deque()
        self._finished = False
        self._after_lock = threading.Lock()  # one command at a time once finished

    def __bool__(self) -> bool:
        return bool(self._commands)

    def send(self, command: Callable[[], T]) -> Future[T]:
        """Queue ``command`` for the worker (or run it here once it finished)."""
        future: Future[T] = Future()
        with self._wake:
            if not self._finished:
                self._commands.append((command, future))
                self._wake.notify()
                return future
        with self._after_lock:
            _run(command, future)
        return future

    def run_pending(self) -> None:
        """Run the commands waiting (the worker's thread)."""
        while self._commands:
            with self._wake:
                if not self._commands:
                    return
                command, future = self._commands.popleft()
            _run(command, future)

    def finish(self) -> None:
        """The worker is done: run what it left, and later commands on their senders."""
        with self._wake:
            self._finished = True
        self.run_pending()


def _run(command: Callable[[], T], future: Future[T]) -> None:
    if not future.set_running_or_notify_cancel():
        return
    try:
        result = command()
    except BaseException as exc:
        log.exception("command failed")
        future.set_exception(exc)
    else:
        future.set_result(result)

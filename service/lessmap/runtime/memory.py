"""Give freed heap memory back to the operating system after sessions leave memory.

CPython's small-object allocator and glibc's malloc keep freed memory for reuse, so after
thousands of sessions are evicted the process stays at its peak size. ``malloc_trim(0)``
(glibc) returns the free pages at the top and in the middle of the heap; elsewhere (musl,
macOS) it is a no-op.

Trimming alone is not enough (``python -m benchmarks.session_flood``, docs/BENCHMARKS.md
"Session flood and memory"): after 10,000 one-frame sessions are evicted, most of what stays
is pymalloc arenas (1 MiB each, given back only when every block in them is free: a few
hundred surviving small objects keep dozens alive) and glibc's per-thread arenas (Zenoh's
runtime threads and the shard workers each may get one). So ``lessmap serve`` starts with
``use_system_malloc`` (CPython's objects on glibc's malloc, where ``malloc_trim`` reaches
free pages between live blocks) and ``tune_allocator`` (two arenas, large blocks in their
own mappings, a low trim threshold), before Zenoh starts its threads.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os
import sys
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger(__name__)


# mallopt parameters (glibc's malloc.h), the environment variable that sets each one at
# glibc's start (the operator's value wins: tune_allocator leaves that one alone), our value.
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8
ALLOCATOR_SETTINGS: tuple[tuple[str, int, str, int], ...] = (
    # Two arenas, not 8 per core: Zenoh's many runtime threads otherwise each keep their own
    # arena and its free memory.
    ("arena_max", M_ARENA_MAX, "MALLOC_ARENA_MAX", 2),
    # Blocks from 128 KiB (CovGraph matrices, big payloads) get their own mapping, unmapped
    # when freed; glibc's default raises this threshold up to 32 MiB as such blocks are freed,
    # and then keeps them in the heap.
    ("mmap_threshold", M_MMAP_THRESHOLD, "MALLOC_MMAP_THRESHOLD_", 128 * 1024),
    # Give the top of a heap back from 128 KiB free (the dynamic default rises with the above).
    ("trim_threshold", M_TRIM_THRESHOLD, "MALLOC_TRIM_THRESHOLD_", 128 * 1024),
)


def _libc_function(name: str) -> Callable[..., int] | None:
    path = ctypes.util.find_library("c")
    if path is None:
        return None
    try:
        function = getattr(ctypes.CDLL(path), name)
    except (OSError, AttributeError):
        return None
    return cast("Callable[..., int]", function)


def _load_trim() -> Callable[[int], int] | None:
    trim = _libc_function("malloc_trim")
    if trim is None:
        return None
    trim.argtypes = [ctypes.c_size_t]  # type: ignore[attr-defined]
    trim.restype = ctypes.c_int  # type: ignore[attr-defined]
    return trim


_TRIM = _load_trim()


def tune_allocator(environ: dict[str, str] | None = None) -> dict[str, int]:
    """Set glibc's malloc options for a long-running service; return what was set.

    Call it before other threads start (before Zenoh opens): a thread that already has its
    own arena keeps it. Nothing is set where the environment already sets that option, or
    when ``GLIBC_TUNABLES`` is set (the operator tuned malloc), or without glibc.
    """
    env = os.environ if environ is None else environ
    mallopt = _libc_function("mallopt") if _TRIM is not None else None
    if mallopt is None or "GLIBC_TUNABLES" in env:
        return {}
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]  # type: ignore[attr-defined]
    mallopt.restype = ctypes.c_int  # type: ignore[attr-defined]
    applied = {}
    for name, param, variable, value in ALLOCATOR_SETTINGS:
        if variable not in env and mallopt(param, value) == 1:
            applied[name] = value
    return applied


def use_system_malloc(argv: list[str] | None = None) -> None:
    """Restart this process (same PID) with ``PYTHONMALLOC=malloc``, unless already set.

    Only where glibc's ``malloc_trim`` exists: it is what gives the free pages back. The
    process image is replaced by the same command line (``sys.orig_argv``): call it before
    anything else started (threads, sockets, files). ``PYTHONMALLOC=pymalloc`` in the
    environment keeps CPython's small-object allocator.
    """
    if _TRIM is None or "PYTHONMALLOC" in os.environ:
        return
    command = list(sys.orig_argv) if argv is None else argv
    if not command:
        return
    os.environ["PYTHONMALLOC"] = "malloc"
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os.execv(sys.executable, [sys.executable, *command[1:]])


def _clear_type_cache() -> None:
    """Drop CPython's type attribute cache, and the attribute names it holds."""
    # The cache keeps a reference to the name of each lookup, in a slot picked by the name's
    # address. numpy looks attributes up by C string ("setflags" at every
    # ``flags.writeable = False``, "accumulate" at every cumsum: a new str each time), so up
    # to 4096 such strings stay alive at random places of the heap. After a flood of 10,000
    # sessions ~3,000 of them kept as many 4 KiB pages resident (docs/BENCHMARKS.md).
    # Refilled by the next lookups; clearing costs microseconds.
    clear = getattr(sys, "_clear_type_cache", None)
    if clear is not None:
        clear()


def trim_heap() -> bool:
    """Return free heap pages to the OS (glibc ``malloc_trim``) only: no collection."""
    return _TRIM is not None and bool(_TRIM(0))


def release_free_memory() -> bool:
    """Free what only CPython's caches still hold, then return free heap pages to the OS.

    A full collection (it also empties CPython's free lists of tuples, lists, dicts and
    floats: up to 2,000 tuples of each size stay there, each one pinning its page), the type
    attribute cache, then glibc's ``malloc_trim``. True when trimmed. Called after sessions
    left memory (by the store's writer once it has written them, at most once a second),
    not per frame: a full collection costs milliseconds.
    """
    gc.collect()
    _clear_type_cache()
    return trim_heap()

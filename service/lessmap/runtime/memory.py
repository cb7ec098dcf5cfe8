"""Give freed heap memory back to the operating system after sessions leave memory.

CPython's small-object allocator and glibc's malloc keep freed memory for reuse, so after
thousands of sessions are evicted the process stays at its peak size. ``malloc_trim(0)``
(glibc) returns the free pages at the top and in the middle of the heap; elsewhere (musl,
macOS) it is a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger(__name__)


def _load_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        trim = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return cast("Callable[[int], int]", trim)


_TRIM = _load_trim()


def release_free_memory() -> bool:
    """Collect garbage, then return freed heap pages to the OS; True when trimmed.

    Called after a sweep evicted sessions (at most once a second per shard), not per frame:
    a full collection costs milliseconds.
    """
    gc.collect()
    if _TRIM is None:
        return False
    return bool(_TRIM(0))

"""Rule 1, minimum evidence: frames pooled into one proposer frame.

A pool closes when it holds ``min_features`` distinct features or spans ``max_frames``
frames. Pools are numbered from 0: the proposer sees pool ``i`` as its frame ``seq = i``,
so its boundaries come back as pool numbers, which ``first_seq`` turns into frames.
"""

from __future__ import annotations

from collections import deque


class Pool:
    """The pool being filled, and the first frame of each recent pool."""

    def __init__(self, min_features: int, max_frames: int, history: int) -> None:
        """Start empty; remember the first frames of the last ``history`` pools."""
        self.min_features = min_features
        self.max_frames = max_frames
        self.features: set[int] = set()
        self.first_seq: int | None = None  # first frame of the pool being filled
        self.frames = 0
        self.index = 0  # number of the pool being filled
        self.starts: deque[tuple[int, int]] = deque(maxlen=history)  # (pool, first seq)

    def add(self, seq: int, features: tuple[int, ...]) -> tuple[int, list[int]] | None:
        """Add one frame; return the pool it closes (number, features ascending), if any."""
        if self.first_seq is None:
            self.first_seq = seq
        self.features.update(features)
        self.frames += 1
        if len(self.features) < self.min_features and self.frames < self.max_frames:
            return None
        closed = (self.index, sorted(self.features))
        self.starts.append((self.index, self.first_seq))
        self.index += 1
        self.features.clear()
        self.first_seq = None
        self.frames = 0
        return closed

    def start_of(self, index: int, default: int) -> int:
        """The first frame of pool ``index`` (``default`` once it is forgotten)."""
        # Pools are remembered in a run of consecutive numbers: an offset finds one.
        offset = index - self.starts[0][0] if self.starts else -1
        return self.starts[offset][1] if 0 <= offset < len(self.starts) else default

    def forget_before(self, index: int) -> None:
        """Forget the first frames of pools numbered below ``index`` (never looked up again)."""
        while self.starts and self.starts[0][0] < index:
            self.starts.popleft()

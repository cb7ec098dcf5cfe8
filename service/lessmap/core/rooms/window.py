"""Rules 1-2: the frame window, its learnt width, and the cut of its two halves.

A frame's similarity to another is the paper's CovRate between two frames, shared features
over the smaller frame's. Each new non-empty frame is compared once with the frames kept
before it; the window's matrix is assembled from those rows, so a frame costs at most
``3 * window_max_frames - 1`` set intersections and one small numpy reduction.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lessmap.core import lagprofile
from lessmap.core.rooms.params import RoomParams

Frame = tuple[int, frozenset[int]]  # (seq, distinct features), non-empty


@dataclass(frozen=True, slots=True)
class Cut:
    """The cut of the window at one boundary: its score and the paper's figures."""

    boundary_seq: int  # first frame of the newer half
    score: float  # within-half minus across-half mean similarity (rule 2)
    width: int  # frames in the older half
    ahead: int  # frames in the newer half (the decision's lag)


def covrate(a: frozenset[int], b: frozenset[int]) -> float:
    """Shared features over the smaller frame's (both non-empty)."""
    return len(a & b) / min(len(a), len(b))


class FrameWindow:
    """The last non-empty frames, their similarities, and the learnt lag profile."""

    def __init__(self, params: RoomParams) -> None:
        """An empty window."""
        self.params = params
        capacity = 3 * params.window_max_frames
        self.frames: deque[Frame] = deque(maxlen=capacity)
        # rows[i][d - 1]: similarity of frames[i] to the frame d places before it (0 if none)
        self.rows: deque[NDArray[np.float64]] = deque(maxlen=capacity)
        # mean similarity of frames d apart (index d - 1) and how many pairs it has seen
        self.lag_mean = np.zeros(capacity - 1, dtype=np.float64)
        self.lag_seen = np.zeros(capacity - 1, dtype=np.int64)

    def add(self, seq: int, features: frozenset[int]) -> None:
        """Take one non-empty frame: its row of similarities and the lag profile."""
        span = self.frames.maxlen or 1
        row = np.zeros(span - 1, dtype=np.float64)
        for d, (_, earlier) in enumerate(reversed(self.frames), start=1):
            if d >= span:
                break  # the oldest frame leaves as this one enters
            row[d - 1] = covrate(features, earlier)
        self.frames.append((seq, features))
        self.rows.append(row)
        lags = len(self.frames) - 1
        lagprofile.learn(self.lag_mean, self.lag_seen, row[:lags], self.params.lag_smoothing)

    def width(self) -> int | None:
        """Frames in a half: the first lag at which the view has changed enough (rule 1).

        None until the profile knows a lag where similarity fell to ``window_similarity``
        of its ceiling (of 1 without ``window_relative``) or it has seen every lag up to
        the maximum.
        """
        p = self.params
        bar = p.window_similarity * (self.ceiling() if p.window_relative else 1.0)
        return lagprofile.first_lag_at(
            self.lag_mean, self.lag_seen, bar, p.window_min_frames, p.window_max_frames
        )

    def ceiling(self) -> float:
        """The CovRate of two frames seen from one place (``lagprofile.ceiling``)."""
        return lagprofile.ceiling(self.lag_mean, self.lag_seen)

    def matrix(self, n: int) -> NDArray[np.float64]:
        """Similarities of the last ``n`` frames, symmetric, zero diagonal."""
        rows = np.stack(list(self.rows)[-n:])
        i, j = np.tril_indices(n, -1)
        m = np.zeros((n, n), dtype=np.float64)
        m[i, j] = rows[i, i - j - 1]
        return m + m.T

    def cut(self, since_seq: int | None = None) -> Cut | None:
        """The cut between the newest frames and the frames before them (rule 2).

        The newer half holds ``ahead_share`` of a half's frames: a change is told after
        that many frames past its boundary. The older half holds ``width`` frames, or those
        of the open segment (from ``since_seq``) if fewer, but at least the minimum: a cut
        compares the segment's own frames with the newest, never frames across a change.
        """
        w = self.width()
        if w is None:
            return None
        least = self.params.window_min_frames
        r = max(least, round(w * self.params.ahead_share))
        if len(self.frames) < r + least:
            return None
        if since_seq is not None:
            own = sum(1 for seq, _ in self.frames if seq >= since_seq) - r
            w = min(w, own)
        w = min(w, len(self.frames) - r)
        if w < least:
            return None
        m = self.matrix(w + r)
        within = (m[:w, :w].sum() / (w * (w - 1)) + m[w:, w:].sum() / (r * (r - 1))) / 2.0
        across = m[:w, w:].mean()
        score = float(within - across) - self.walking(w, r)
        return Cut(boundary_seq=self.frames[-r][0], score=score, width=w, ahead=r)

    def walking(self, w: int, r: int) -> float:
        """The cut a steady walk makes: across-half pairs lie further apart than within-half ones.

        From the lag profile: the mean similarity of the pairs of each kind at their lags.
        A cut counts only what the view changed beyond that.
        """
        lag = self.lag_mean
        within = 0.0
        for n in (w, r):
            d = np.arange(1, n)
            within += float(np.dot(n - d, lag[d - 1])) / (n * (n - 1) / 2) / 2.0
        d = np.arange(1, w + r)
        pairs = np.minimum(np.minimum(d, w), np.minimum(r, w + r - d))
        across = float(np.dot(pairs, lag[d - 1])) / (w * r)
        return within - across

    def figures(self, boundary_seq: int) -> tuple[float, float]:
        """Ncut and λ2 of the window's frame graph split at ``boundary_seq`` (for reports).

        The window's frames are the nodes and their CovRate the weights: the split is the
        temporal bipartition the cut chose, scored as Shi–Malik score any bipartition.
        """
        seqs = [seq for seq, _ in self.frames]
        n = len(seqs)
        m = self.matrix(n)
        new = np.array([seq >= boundary_seq for seq in seqs])
        cut = float(m[new][:, ~new].sum())
        degree = m.sum(axis=1)
        ncut = 0.0
        for side in (new, ~new):
            assoc = float(degree[side].sum())
            ncut += cut / assoc if assoc > 0 else 1.0
        safe = np.where(degree > 0, degree, 1.0)
        scale = 1.0 / np.sqrt(safe)
        normalized = np.eye(n) - scale[:, None] * m * scale[None, :]
        values = np.linalg.eigvalsh(normalized)
        return ncut, float(values[1]) if n > 1 else 0.0

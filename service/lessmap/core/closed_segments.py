"""The closed segments an area-naming segmenter keeps, compact and cheap to checkpoint.

A session keeps up to ``PartitionParams.keep_closed_submaps`` (1,000) closed segments for
queries, and every checkpoint writes them. As ``Submap`` tuples of Python ints they cost
~36 bytes a feature and a Python loop per checkpoint; as one numpy array a segment, ~0.8 KiB
a segment of 65 features, most of it per-object overhead. Here all segments share three flat
buffers: the rows, the feature offsets and the features, as int32 while every ID fits (int64
from the first that does not), about 0.3 KiB a segment. ``pack`` hands out slices of them,
so a checkpoint copies no segment one by one. Segments go in closed and come back out as
equal ``Submap`` objects; ``segmenter_snapshot.submaps_unpack`` reads ``pack`` back.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.core.paper.submaps import Submap

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

    from numpy.typing import NDArray

_INT32 = np.iinfo(np.int32)
_FIRST_ROWS = 8  # a new session's buffers start this small and double as segments close
_FIRST_VALUES = 256


class ClosedSegments:
    """The last ``bound`` closed segments, oldest first."""

    def __init__(self, bound: int, segments: Iterable[Submap] = ()) -> None:
        """Keep at most ``bound`` segments (the oldest go first); start with ``segments``."""
        self._bound = bound
        # Segment i (self._first <= i < self._end): self._rows[i] = (id, first seq, last seq,
        # frames), its features self._values[self._offsets[i] : self._offsets[i + 1]].
        self._rows = np.zeros((_FIRST_ROWS, 4), dtype=np.int64)
        self._offsets = np.zeros(_FIRST_ROWS + 1, dtype=np.int64)
        self._values: NDArray[np.signedinteger[Any]] = np.zeros(_FIRST_VALUES, dtype=np.int32)
        self._first = 0  # segments before it went past the bound
        self._end = 0
        for segment in segments:
            self.append(segment)

    def append(self, segment: Submap) -> None:
        """Keep one more closed segment."""
        if self._bound <= 0:
            return
        features = np.array(segment.features, dtype=np.int64)
        narrow = self._values.dtype == np.int32 and features.size
        if narrow and (features.min() < _INT32.min or features.max() > _INT32.max):
            self._values = self._values.astype(np.int64)  # IDs past 32 bits: widen once
        if self._end - self._first == self._bound:
            self._first += 1
        self._make_room(features.size)
        end, start = self._end, int(self._offsets[self._end])
        self._rows[end] = (segment.id, segment.first_seq, segment.last_seq, segment.frame_count)
        self._values[start : start + features.size] = features
        self._offsets[end + 1] = start + features.size
        self._end = end + 1

    def _make_room(self, values: int) -> None:
        """Room for one more row and ``values`` more features: compact, else double."""
        if self._end == len(self._rows) and 4 * self._first >= self._end:
            self._compact()  # a quarter of the rows went past the bound: reuse their room
        if self._end == len(self._rows):
            grown = len(self._rows) * 2
            self._rows = np.resize(self._rows, (grown, 4))
            self._offsets = np.resize(self._offsets, grown + 1)
        need = int(self._offsets[self._end]) + values
        if need > self._values.size:
            self._values = np.resize(self._values, max(need, 2 * self._values.size))

    def _compact(self) -> None:
        """Move the kept segments to the front of the buffers."""
        first, end = self._first, self._end
        start, stop = int(self._offsets[first]), int(self._offsets[end])
        kept = end - first
        self._rows[:kept] = self._rows[first:end]
        self._offsets[: kept + 1] = self._offsets[first : end + 1] - start
        self._values[: stop - start] = self._values[start:stop]
        self._first, self._end = 0, kept

    def __len__(self) -> int:
        return self._end - self._first

    def __iter__(self) -> Iterator[Submap]:
        offsets, values = self._offsets, self._values
        for i in range(self._first, self._end):
            segment_id, first, last, frames = self._rows[i].tolist()
            yield Submap(
                id=segment_id,
                first_seq=first,
                last_seq=last,
                frame_count=frames,
                features=tuple(values[offsets[i] : offsets[i + 1]].tolist()),
            )

    def pack(self) -> tuple[list[list[int]], dict[str, NDArray[np.int64]]]:
        """Rows (id, first, last, frames) and the features as ragged arrays, as stored."""
        first, end = self._first, self._end
        start, stop = int(self._offsets[first]), int(self._offsets[end])
        rows: list[list[int]] = self._rows[first:end].tolist()
        return rows, {
            "submap_offsets": self._offsets[first : end + 1] - start,
            "submap_values": self._values[start:stop].astype(np.int64),
        }

"""The closed segments an area-naming segmenter keeps, compact and cheap to checkpoint.

A session keeps up to ``PartitionParams.keep_closed_submaps`` (1,000) closed segments for
queries, and every checkpoint writes them. Held as ``Submap`` tuples of Python ints they cost
~36 bytes a feature and a Python loop per checkpoint, both growing with the session's age;
here each segment's features are one int64 array (8 bytes a feature), and ``pack`` joins them
in C. Segments go in closed and come back out as equal ``Submap`` objects; ``pack`` gives the
rows and ragged arrays that ``segmenter_snapshot.submaps_unpack`` reads back.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from lessmap.core.paper.submaps import Submap

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

    from numpy.typing import NDArray

#: A segment without its features: (id, first seq, last seq, frame count).
Row = tuple[int, int, int, int]


class ClosedSegments:
    """The last ``bound`` closed segments, oldest first."""

    def __init__(self, bound: int, segments: Iterable[Submap] = ()) -> None:
        """Keep at most ``bound`` segments (the oldest go first); start with ``segments``."""
        self._rows: deque[Row] = deque(maxlen=bound)
        self._features: deque[NDArray[np.int64]] = deque(maxlen=bound)
        for segment in segments:
            self.append(segment)

    def append(self, segment: Submap) -> None:
        """Keep one more closed segment."""
        self._rows.append((segment.id, segment.first_seq, segment.last_seq, segment.frame_count))
        features = segment.features
        self._features.append(np.fromiter(features, dtype=np.int64, count=len(features)))

    def __len__(self) -> int:
        return len(self._rows)

    def __iter__(self) -> Iterator[Submap]:
        for (segment_id, first, last, frames), features in zip(
            self._rows, self._features, strict=True
        ):
            yield Submap(
                id=segment_id,
                first_seq=first,
                last_seq=last,
                frame_count=frames,
                features=tuple(features.tolist()),
            )

    def pack(self) -> tuple[list[list[int]], dict[str, NDArray[np.int64]]]:
        """Rows (id, first, last, frames) and the features as ragged arrays, as stored."""
        rows = [list(row) for row in self._rows]
        offsets = np.zeros(len(rows) + 1, dtype=np.int64)
        np.cumsum([f.size for f in self._features], out=offsets[1:])
        values = np.concatenate(self._features) if self._features else np.zeros(0, dtype=np.int64)
        return rows, {"submap_offsets": offsets, "submap_values": values}

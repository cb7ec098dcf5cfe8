"""What an areas session keeps as it ages: closed segments compact, pools its proposer can name."""

from __future__ import annotations

import numpy as np

from lessmap.core.areas.pool import Pool
from lessmap.core.closed_segments import ClosedSegments
from lessmap.core.paper.submaps import Submap
from lessmap.core.segmenter import AreasSegmenter, segmenter_from_bytes
from lessmap.core.segmenter_snapshot import submaps_unpack


def _segment(segment_id: int, features: tuple[int, ...]) -> Submap:
    first = 10 * segment_id
    return Submap(
        id=segment_id,
        first_seq=first,
        last_seq=first + 9,
        frame_count=10,
        features=features,
    )


SEGMENTS = [_segment(0, (1, 2, 3)), _segment(1, ()), _segment(2, (5, 2**40, 7))]


def test_segments_come_back_equal_and_in_order() -> None:
    closed = ClosedSegments(10, SEGMENTS)
    assert len(closed) == 3
    assert list(closed) == SEGMENTS
    assert all(type(f) is int for s in closed for f in s.features)  # plain ints, as before


def test_the_oldest_go_first_past_the_bound() -> None:
    closed = ClosedSegments(2, SEGMENTS)
    assert [s.id for s in closed] == [1, 2]
    closed.append(_segment(3, (9,)))
    assert [s.id for s in closed] == [2, 3]


def test_pack_gives_rows_and_ragged_arrays() -> None:
    rows, arrays = ClosedSegments(10, SEGMENTS).pack()
    assert rows == [[0, 0, 9, 10], [1, 10, 19, 10], [2, 20, 29, 10]]
    assert arrays["submap_offsets"].tolist() == [0, 3, 3, 6]
    assert arrays["submap_values"].tolist() == [1, 2, 3, 5, 2**40, 7]
    assert arrays["submap_values"].dtype == np.int64
    assert submaps_unpack(rows, arrays) == SEGMENTS


def test_pack_of_none() -> None:
    rows, arrays = ClosedSegments(10).pack()
    assert rows == []
    assert arrays["submap_offsets"].tolist() == [0]
    assert arrays["submap_values"].size == 0


def test_a_segmenter_snapshot_keeps_its_closed_segments_exactly() -> None:
    segmenter = AreasSegmenter(closed=SEGMENTS)
    data = segmenter.to_bytes()
    back = segmenter_from_bytes(data)
    assert list(back.closed_submaps) == SEGMENTS
    assert back.to_bytes() == data


def test_a_pools_first_frames_are_forgotten_before_a_number() -> None:
    pool = Pool(min_features=1, max_frames=1, history=100)
    for seq in range(10, 20):
        assert pool.add(seq, (seq,)) is not None  # one pool a frame: pool i starts at 10 + i
    assert pool.start_of(3, -1) == 13
    pool.forget_before(5)
    assert pool.start_of(4, -1) == -1
    assert [pool.start_of(i, -1) for i in range(5, 11)] == [15, 16, 17, 18, 19, -1]
    pool.forget_before(99)
    assert pool.start_of(9, -1) == -1


def test_an_old_areas_session_keeps_only_the_pools_its_proposer_can_name() -> None:
    """Pools older than the proposer's kept history are never looked up again."""
    segmenter = AreasSegmenter()
    for seq in range(3000):
        room = seq // 300  # a new set of features every 300 frames
        segmenter.apply(seq, seq / 10, [1000 * room + k for k in range(20)])
        segmenter.decide()
    tracker = segmenter.tracker
    oldest = tracker.proposer.oldest_boundary_seq
    assert oldest is not None
    assert tracker.pool.starts[0][0] >= oldest
    assert len(tracker.pool.starts) < tracker.params.proposal.history_frames


def test_many_segments_past_a_small_bound_match_a_plain_list() -> None:
    """Compaction and growth of the flat buffers keep exactly the newest ``bound``."""
    rng = np.random.default_rng(3)
    for bound in (1, 2, 3, 8, 13):
        closed = ClosedSegments(bound)
        kept: list[Submap] = []
        for segment_id in range(60):
            size = int(rng.integers(0, 40))
            features = tuple(sorted({int(v) for v in rng.integers(0, 10_000, size)}))
            segment = _segment(segment_id, features)
            closed.append(segment)
            kept = [*kept, segment][-bound:]
            assert list(closed) == kept
            rows, arrays = closed.pack()
            assert submaps_unpack(rows, arrays) == kept


def test_ids_past_32_bits_widen_the_store_and_keep_the_older_ones() -> None:
    closed = ClosedSegments(10, [_segment(0, (1, 2**31 - 1)), _segment(1, (-(2**31),))])
    closed.append(_segment(2, (2**31, -(2**40))))
    closed.append(_segment(3, (2**62,)))
    wanted = [(1, 2**31 - 1), (-(2**31),), (2**31, -(2**40)), (2**62,)]
    assert [s.features for s in closed] == wanted


def test_no_bound_keeps_nothing() -> None:
    closed = ClosedSegments(0, SEGMENTS)
    assert len(closed) == 0
    assert list(closed) == []

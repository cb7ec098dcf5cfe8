"""``AreaParams.spans_in_views``: the areas rules' spans in the stream's own view changes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lessmap.core import lagprofile
from lessmap.core.areas import snapshot
from lessmap.core.areas.params import AreaParams
from lessmap.core.areas.snapshot import from_bytes, to_bytes
from lessmap.core.areas.tracker import AreaTracker
from lessmap.core.paper.framing import frame, unframe

VIEWS = AreaParams(spans_in_views=True, view_every=1)


def sliding(step: int, frames: int, width: int = 25) -> list[list[int]]:
    """A robot whose view moves ``step`` features a frame along an endless wall."""
    return [list(range(k * step, k * step + width)) for k in range(frames)]


def fed(params: AreaParams, stream: list[list[int]]) -> AreaTracker:
    tracker = AreaTracker(params)
    for seq, features in enumerate(stream):
        tracker.observe(seq, seq * 0.1, features)
    return tracker


def test_the_view_length_follows_how_fast_the_view_moves() -> None:
    # 25 features in view, moving 1 a frame: lag d shares (25 - d) / 25, 0.65 of the ceiling
    # (1) first at d = 9; moving 2: (25 - 2d) / 25, first at d = 5.
    slow, fast = fed(VIEWS, sliding(1, 200)), fed(VIEWS, sliding(2, 200))
    assert lagprofile.ceiling(slow.lag_mean, slow.lag_seen) == pytest.approx(1.0)
    # the spans grow by view / view_frames (8): 16 frames become 18; a faster view than the
    # reference's keeps the 16 measured (5 / 8 would make them 10)
    assert (slow._in_views(16), fast._in_views(16)) == (18, 16)
    assert fed(AreaParams(), sliding(3, 200))._in_views(16) == 16
    assert fed(AreaParams(), sliding(1, 200))._in_views(16) == 18  # on by default
    off = AreaParams(spans_in_views=False)
    assert fed(off, sliding(1, 200))._in_views(16) == 16  # off: frames
    assert AreaTracker(VIEWS)._in_views(16) == 16  # nothing learnt yet: frames


def test_off_learns_nothing_and_keeps_no_profile() -> None:
    tracker = fed(AreaParams(spans_in_views=False), sliding(1, 100))
    assert not tracker.lag_seen.any()
    meta, _ = unframe(to_bytes(tracker), snapshot._MAGIC, snapshot._ARRAYS)
    assert meta["view_lag_mean"] == meta["view_lag_seen"] == []


def rooms_walk(visits: int, frames_per_room: int) -> list[list[int]]:
    """Three rooms of 30 landmarks, visited in turn, 12 landmarks in view drifting."""
    rng = np.random.default_rng(7)
    stream = []
    for visit in range(visits):
        room = visit % 3
        for k in range(frames_per_room):
            start = 100 * room + (k % 18)
            view = [f for f in range(start, start + 12) if rng.random() < 0.9]
            stream.append(view)
    return stream


@pytest.mark.parametrize("cut", [37, 120, 251])
def test_a_restored_session_decides_as_the_uninterrupted_one(cut: int) -> None:
    stream = rooms_walk(9, 40)
    whole = AreaTracker(VIEWS)
    events = [whole.observe(seq, seq * 0.1, f) for seq, f in enumerate(stream)]
    first = AreaTracker(VIEWS)
    for seq, features in enumerate(stream[:cut]):
        first.observe(seq, seq * 0.1, features)
    data = to_bytes(first)
    resumed = from_bytes(data)
    assert to_bytes(resumed) == data
    assert np.array_equal(resumed.lag_mean, first.lag_mean)
    assert np.array_equal(resumed.lag_seen, first.lag_seen)
    later = [resumed.observe(seq, seq * 0.1, f) for seq, f in enumerate(stream) if seq >= cut]
    assert later == events[cut:]
    assert any(event is not None for event in events)


def test_a_version_10_snapshot_resumes_with_spans_in_frames() -> None:
    """Sessions checkpointed before the option resume as they ran: spans in frames."""
    tracker = fed(AreaParams(spans_in_views=False), rooms_walk(3, 40))
    meta, arrays = unframe(to_bytes(tracker), snapshot._MAGIC, snapshot._ARRAYS)
    meta["version"] = 10
    for key in ("view_lag_mean", "view_lag_seen"):
        del meta[key]
    del meta["params"]["spans_in_views"]
    old = from_bytes(frame(snapshot._MAGIC, meta, arrays))
    assert old.params == replace(tracker.params, spans_in_views=False)
    assert to_bytes(old) == to_bytes(tracker)


def test_the_view_parameters_are_checked() -> None:
    from lessmap.core.errors import GraphError

    for field, value in [("view_share", 1.0), ("view_frames", 0), ("view_max_lag", 1)]:
        with pytest.raises(GraphError, match=field):
            AreaParams(**{field: value})  # type: ignore[arg-type]


def test_a_damaged_lag_profile_is_a_graph_error() -> None:
    from lessmap.core.errors import GraphError

    meta, arrays = unframe(to_bytes(fed(VIEWS, sliding(1, 50))), snapshot._MAGIC, snapshot._ARRAYS)
    meta["view_lag_mean"] = ["not a float"] * 3
    with pytest.raises(GraphError, match="not an area snapshot"):
        from_bytes(frame(snapshot._MAGIC, meta, arrays))
    meta["view_lag_mean"] = ["0x0p+0"] * (VIEWS.view_max_lag + 1)  # longer than the profile
    with pytest.raises(GraphError, match="not an area snapshot"):
        from_bytes(frame(snapshot._MAGIC, meta, arrays))

"""The tests of rules 3-5 (``lessmap.core.areas.tracker``) over an ``AreaTracker``'s kept frames.

Pure functions of the frames of the current segment (oldest first) and the areas' counts;
the tracker decides what to do with their answers.
"""

from __future__ import annotations

from bisect import bisect_left
from typing import TYPE_CHECKING

from lessmap.core.areas.profile import tally, without

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence

    from lessmap.core.areas.profile import Frame, Profile


def sides(
    frames: Iterable[Frame], segment_counts: dict[int, int], boundary: int
) -> tuple[dict[int, int], dict[int, int], int]:
    """Split the segment at the boundary.

    Returns:
        Sightings per feature from the boundary on, the features seen before it, and
        the number of non-empty frames from the boundary on.
    """
    after, moved = tally(frame for frame in frames if frame[0] >= boundary)
    return after, without(segment_counts, after), moved


def blind_before(frames: Iterable[Frame], boundary: int, blind_frames: int) -> bool:
    """Whether the first sighting from the boundary on follows ``blind_frames`` empty frames.

    Rule 3b. A pool may start on an empty frame, so the empty frames right after the
    boundary count too.
    """
    if not blind_frames:
        return False
    empty = 0
    for frame_seq, features in frames:
        if features:
            if frame_seq >= boundary:
                break
            empty = 0
        else:
            empty += 1
    return empty >= blind_frames


def blind_start(frames: Sequence[Frame], boundary: int, margin: int) -> int:
    """Where rule 3b looks for blind frames from: ``margin`` non-empty frames before the boundary.

    The boundary itself when ``margin`` is 0; the first kept frame before it that is
    non-empty when fewer than ``margin`` are kept.
    """
    if margin:
        earlier = [s for s, features in frames if features and s < boundary]
        if earlier:
            return earlier[-min(margin, len(earlier))]
    return boundary


def blind_run(frames: Sequence[Frame], boundary: int, margin: int) -> int:
    """Longest run of empty frames from ``margin`` non-empty frames before the boundary on.

    Rule 3b: the run may also lie after the boundary (a pool may start on empty frames).
    """
    start = blind_start(frames, boundary, margin)
    best = run = 0
    for frame_seq, features in frames:
        if frame_seq < start:
            continue
        if features:
            run = 0
        else:
            run += 1
            best = max(best, run)
    return best


def missing_frames(step: float, steps: Iterable[float]) -> int:
    """Frames a stamp step leaves out at the period of ``steps`` (their median; rule 3b).

    A step of about ``k + 1`` periods (rounded) leaves out ``k`` frames; 0 without steps.
    """
    ordered = sorted(steps)
    if not ordered:
        return 0
    middle = len(ordered) // 2
    period = ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2
    return max(0, round(step / period) - 1)


def blind_gap(
    frames: Sequence[Frame],
    gaps: Iterable[tuple[int, int]],
    boundary: int,
    least: tuple[int, int],
    margin: int,
) -> bool:
    """Whether frames a stamp gap left out make the boundary blind, as empty frames would.

    Rule 3b on ``gaps``, (frame, frames missing right before it) of the kept frames:
    ``least[0]`` (``blind_frames``) missing right before the first sighting from the
    boundary on, as ``blind_before`` counts, or ``least[1]`` (``blind_span``) missing
    before a frame after the one ``margin`` non-empty frames before the boundary, as
    ``blind_run`` counts (a gap before that frame lies outside).
    """
    before_first, in_span = least
    first = next((seq for seq, features in frames if features and seq >= boundary), None)
    start = blind_start(frames, boundary, margin)
    for seq, missing in gaps:
        if before_first and seq == first and missing >= before_first:
            return True
        if in_span and seq > start and missing >= in_span:
            return True
    return False


def seam(
    frames: Sequence[Frame], segment_counts: dict[int, int], boundary: int, width: int, least: int
) -> int:
    """Where the segment entered starts: at most ``width`` frames after the boundary (rule 7).

    Of the kept frames from ``boundary`` to ``width`` frames after it, the one with the most
    features seen both in the ``width`` frames before it and in the ``width`` frames from it
    on (ties: the earliest), among those that leave ``least`` distinct features on each
    side of the segment; ``boundary`` when ``width`` is 0 or no other frame qualifies.
    """
    if not width:
        return boundary
    seqs = [frame_seq for frame_seq, _ in frames]
    at = bisect_left(seqs, boundary)
    if at >= len(seqs) or seqs[at] != boundary:
        return boundary
    kept = [features for _, features in frames]

    def shared(i: int) -> int:
        left = {f for features in kept[max(0, i - width) : i] for f in features}
        right = {f for features in kept[i : i + width] for f in features}
        return len(left & right)

    order = sorted(range(at, min(len(seqs) - 1, at + width) + 1), key=lambda i: (-shared(i), i))
    for i in order:
        if i == at:
            return boundary
        after, before, _ = sides(frames, segment_counts, seqs[i])
        if len(after) >= least and len(before) >= least:
            return seqs[i]
    return boundary


def familiar_share(
    frames: Sequence[Frame],
    counts: dict[int, int],
    area_frames: int,
    boundary: int,
    after: dict[int, int],
    *,
    rate: float,
    margin: int,
    relative: float = 0.0,
) -> float:
    """Share of the new frames' sightings the current area knows well (rule 3c).

    Args:
        frames: the kept frames of the current segment.
        counts: the current area's sightings per feature (the segment's included).
        area_frames: the current area's non-empty frames (the segment's included).
        boundary: the first frame of the new side.
        after: sightings per feature from the boundary on.
        rate: ``familiar_rate``.
        margin: ``familiar_margin_frames``.
        relative: ``familiar_relative`` (0: the rate alone decides).
    """
    start = boundary
    if margin:
        earlier = [s for s, features in frames if features and s < boundary]
        if earlier:
            start = earlier[-min(margin, len(earlier))]
    left_out, left_frames = tally(frame for frame in frames if frame[0] >= start)
    remaining = area_frames - left_frames
    if remaining <= 0:
        return 0.0
    least = rate * remaining
    if relative:
        # the mean count of the features the area keeps (a sparse sensor's rates are all low)
        kept = [n for n in (m - left_out.get(f, 0) for f, m in counts.items()) if n > 0]
        if kept:
            least = min(least, relative * sum(kept) / len(kept))
    familiar = 0
    for feature, n in after.items():
        seen = counts.get(feature, 0) - left_out.get(feature, 0)
        if seen > 0 and seen >= least:
            familiar += n
    return familiar / sum(after.values())


def seen_share(counts: dict[int, int], after: dict[int, int]) -> float:
    """Share of the features in ``after`` that an area's ``counts`` hold (rule 4)."""
    return sum(1 for feature in after if feature in counts) / len(after)


def known_area(
    areas: Sequence[dict[int, int]],
    live: Iterable[int],
    current: int,
    after: dict[int, int],
    least: float,
) -> tuple[int | None, float]:
    """The known area (not the current one) that has seen most of ``after`` (rule 4).

    None, 0 when no area has seen a share ``least`` of its features.
    """
    best: int | None = None
    share = 0.0
    for area in live:
        counts = areas[area]
        if area == current or not counts:
            continue
        seen = seen_share(counts, after)
        if seen > share:
            best, share = area, seen
    if best is None or share < least:
        return None, 0.0
    return best, share


def last_nonempty(frames: Sequence[Frame], count: int) -> Sequence[Frame] | None:
    """The last ``count`` non-empty frames, oldest first (None if fewer)."""
    found: list[Frame] = []
    for frame in reversed(frames):
        if frame[1]:
            found.append(frame)
            if len(found) == count:
                return found[::-1]
    return None


def best_fit(
    window: Sequence[Frame],
    here: Profile,
    live: Iterable[int],
    profile_of: Callable[[int], Profile | None],
    least_llr: float,
) -> int | None:
    """The area whose profile fits every frame of ``window`` better than ``here`` (rule 5).

    Of the areas that fit each frame better, by ``least_llr`` nats per frame on average,
    the one with the largest average; None when there is none. ``profile_of`` gives None
    for the current area and for areas without frames.
    """
    # The current area's fit of each frame, computed when first read: most areas fail the
    # first frame, so the later ones are rarely needed (the same floats either way).
    fits_here: list[float] = []
    best: int | None = None
    best_gain = 0.0
    for area in live:
        there = profile_of(area)
        if there is None:
            continue
        gains: list[float] = []
        for at, (_, features) in enumerate(window):
            if at == len(fits_here):
                fits_here.append(here.loglik(features))
            gain = there.loglik(features) - fits_here[at]
            if gain <= 0:
                break  # it must fit every frame better: most areas fail the first one
            gains.append(gain)
        else:
            mean = sum(gains) / len(gains)
            if mean >= least_llr and mean > best_gain:
                best, best_gain = area, mean
    return best


def walk_back(
    frames: Sequence[Frame], boundary: int, first: int, there: Profile, here: Profile
) -> int:
    """Move a recognised boundary back over the earlier frames that fit ``there`` better.

    Stops at the first non-empty frame that does not, and never reaches the segment's first
    frame ``first``.
    """
    for frame_seq, features in reversed(frames):
        if frame_seq >= boundary:
            continue
        if frame_seq <= first:
            break
        if not features:
            continue
        if there.loglik(features) <= here.loglik(features):
            break
        boundary = frame_seq
    return boundary

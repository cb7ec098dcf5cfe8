"""Query replies every reader accepts: a state or an area graph over the limits is cut to fit.

Readers refuse a payload over ``max_payload_bytes`` or a list over ``max_list_len``
(schemas/README.md section 8); a long session's state or area graph can get there.

1. A reply within the limits is sent as it is (one encode, the only cost on the usual path).
2. A ``SessionState`` over them keeps its most recent closed submaps, as many as fit.
3. An ``AreaGraph`` over them first empties the ``features`` of the areas visited longest
   ago, as many as needed; then leaves those areas out with their passages. The area the
   robot is in goes last.
4. The cut is the smallest that fits, found by bisection over whole encodes.
5. Pure functions over the wire models: no I/O; the caller logs and counts what was cut.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import msgpack

if TYPE_CHECKING:
    from collections.abc import Callable

    from lessmap_schemas.limits import WireLimits
    from lessmap_schemas.messages import AreaGraph, SessionState


def _pack(document: dict[str, Any]) -> bytes:
    data: bytes = msgpack.packb(document, use_bin_type=True)  # ``encode`` of a model_dump
    return data


def _fits(
    data: bytes, document: dict[str, Any], limits: WireLimits, lists: tuple[str, ...]
) -> bool:
    if len(data) > limits.max_payload_bytes:
        return False
    return all(len(document[name]) <= limits.max_list_len for name in lists)


def _least(n: int, fits: Callable[[int], bool]) -> int | None:
    """The least k in 0..n with fits(k), fits being monotone; None when not even n fits."""
    if not fits(n):
        return None
    low, high = 0, n
    while low < high:
        middle = (low + high) // 2
        if fits(middle):
            high = middle
        else:
            low = middle + 1
    return low


def fit_state(state: SessionState, limits: WireLimits) -> tuple[bytes, int]:
    """Return the state's payload within the limits, and how many closed submaps it left out."""
    document = state.model_dump()
    data = _pack(document)  # what ``encode`` gives, the document kept for a cut
    if _fits(data, document, limits, ("closed_submaps",)):
        return data, 0
    closed = document["closed_submaps"]

    def without_oldest(k: int) -> dict[str, Any]:
        return {**document, "closed_submaps": closed[k:]}

    def fits(k: int) -> bool:
        cut = without_oldest(k)
        return _fits(_pack(cut), cut, limits, ("closed_submaps",))

    dropped = _least(len(closed), fits)
    if dropped is None:  # not even without any closed submap: nothing smaller to send
        dropped = len(closed)
    return _pack(without_oldest(dropped)), dropped


def fit_area_graph(graph: AreaGraph, limits: WireLimits) -> tuple[bytes, int]:
    """Return the graph's payload within the limits, and how many areas lost something."""
    document = graph.model_dump()
    data = _pack(document)  # what ``encode`` gives, the document kept for a cut
    lists = ("areas", "passages")
    if _fits(data, document, limits, lists):
        return data, 0
    areas = document["areas"]
    oldest_first = sorted(range(len(areas)), key=lambda i: (areas[i]["last_seq"], areas[i]["id"]))

    def emptied(k: int) -> dict[str, Any]:
        gone = set(oldest_first[:k])
        kept = [{**a, "features": []} if i in gone else a for i, a in enumerate(areas)]
        return {**document, "areas": kept}

    def left_out(k: int) -> dict[str, Any]:
        base = emptied(len(areas))
        gone_ids = {areas[i]["id"] for i in oldest_first[:k]}
        kept = [a for a in base["areas"] if a["id"] not in gone_ids]
        passages = [
            p for p in document["passages"] if p["a"] not in gone_ids and p["b"] not in gone_ids
        ]
        return {**base, "areas": kept, "passages": passages}

    def fits_with(make: Callable[[int], dict[str, Any]]) -> Callable[[int], bool]:
        def fits(k: int) -> bool:
            cut = make(k)
            return _fits(_pack(cut), cut, limits, lists)

        return fits

    emptied_count = _least(len(areas), fits_with(emptied))
    if emptied_count is not None:
        return _pack(emptied(emptied_count)), emptied_count
    dropped = _least(len(areas), fits_with(left_out))
    return _pack(left_out(len(areas) if dropped is None else dropped)), len(areas)

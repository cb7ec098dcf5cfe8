"""Replies over the wire limits are cut to what readers accept (``lessmap.runtime.replies``).

Pure functions on real wire messages, checked by the reference reader with the same limits;
then one real ``lessmap serve`` with a small ``max_payload_bytes`` answering a long state.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import pytest

from lessmap.runtime.replies import fit_area_graph, fit_state
from lessmap_client import RobotPublisher
from lessmap_schemas import keys
from lessmap_schemas.codec import decode, encode
from lessmap_schemas.limits import DEFAULT_LIMITS
from lessmap_schemas.messages import AreaGraph, AreaNode, Passage, SessionState, SubmapSummary
from tests.conftest import metric_value, wait_until

if TYPE_CHECKING:
    from collections.abc import Callable

    import zenoh

    from tests.conftest import ServeProcess

BIG = 2**62  # a hashed feature id: 9 bytes in msgpack


def submap(i: int, features: int) -> SubmapSummary:
    ids = [BIG + 1000 * i + k for k in range(features)]
    return SubmapSummary(id=i, first_seq=10 * i, last_seq=10 * i + 9, frame_count=10, features=ids)


def state(closed: int, features: int) -> SessionState:
    return SessionState(
        fleet="f",
        robot="r",
        session="s",
        incarnation=0,
        instance="i",
        epoch=1,
        open=True,
        last_seq=10 * closed + 9,
        frames_applied=10 * closed + 10,
        frames_duplicate=0,
        frames_missing=0,
        frames_rejected=0,
        transitions=closed,
        method="paper",
        current_area=closed,
        current_submap=submap(closed, features),
        closed_submaps=[submap(i, features) for i in range(closed)],
        nodes=features,
        edges=0,
    )


def test_a_state_within_the_limits_is_sent_as_it_is() -> None:
    message = state(20, 50)
    assert fit_state(message, DEFAULT_LIMITS) == (encode(message), 0)


def test_a_state_over_the_payload_keeps_its_most_recent_closed_submaps() -> None:
    message = state(300, 500)  # 300 x 500 ids x 9 B: ~1.4 MB
    assert len(encode(message)) > DEFAULT_LIMITS.max_payload_bytes
    payload, dropped = fit_state(message, DEFAULT_LIMITS)
    assert len(payload) <= DEFAULT_LIMITS.max_payload_bytes
    got = decode(payload, SessionState, DEFAULT_LIMITS)  # the reference reader accepts it
    assert 0 < dropped < 300
    assert got.closed_submaps == message.closed_submaps[dropped:]  # the newest, in order
    assert got.current_submap == message.current_submap
    # the smallest cut: one submap more would not fit
    one_more = message.model_copy(update={"closed_submaps": message.closed_submaps[dropped - 1 :]})
    assert len(encode(one_more)) > DEFAULT_LIMITS.max_payload_bytes


def test_a_state_over_the_list_length_keeps_as_many_as_are_allowed() -> None:
    limits = replace(DEFAULT_LIMITS, max_list_len=40)
    payload, dropped = fit_state(state(50, 3), limits)
    got = decode(payload, SessionState, limits)
    assert dropped == 10
    assert [s.id for s in got.closed_submaps] == list(range(10, 50))


def graph(areas: int, features: int) -> AreaGraph:
    # Area i was last visited at seq 1000 - i for i > 0: area 0 is the latest (current),
    # area 1 the one visited just before, ..., the highest id the longest ago.
    nodes = [
        AreaNode(
            id=i,
            frames=10,
            visits=1,
            first_seq=0,
            last_seq=2000 if i == 0 else 1000 - i,
            features=[BIG + 1000 * i + k for k in range(features)],
        )
        for i in range(areas)
    ]
    passages = [
        Passage(a=i, b=i + 1, a_to_b=1, b_to_a=0, boundary_features=[[BIG + i, 1]])
        for i in range(areas - 1)
    ]
    return AreaGraph(
        fleet="f",
        robot="r",
        session="s",
        instance="i",
        epoch=1,
        method="areas",
        areas=nodes,
        passages=passages,
    )


def test_an_area_graph_over_the_payload_empties_the_areas_visited_longest_ago() -> None:
    message = graph(200, 800)  # 200 x 800 ids x 9 B: ~1.4 MB
    payload, cut = fit_area_graph(message, DEFAULT_LIMITS)
    assert len(payload) <= DEFAULT_LIMITS.max_payload_bytes
    got = decode(payload, AreaGraph, DEFAULT_LIMITS)
    assert 0 < cut < 200
    assert [a.id for a in got.areas] == list(range(200))  # every area still listed
    assert got.passages == message.passages
    emptied = [a.id for a in got.areas if not a.features]
    assert emptied == list(range(200 - cut, 200))  # the longest ago first
    assert got.areas[0] == message.areas[0]  # the current area keeps its features


def test_an_area_graph_over_the_list_length_leaves_out_the_oldest_areas() -> None:
    limits = replace(DEFAULT_LIMITS, max_list_len=50)
    payload, cut = fit_area_graph(graph(80, 2), limits)
    got = decode(payload, AreaGraph, limits)
    assert cut == 80
    assert [a.id for a in got.areas] == list(range(50))  # the 50 visited last
    assert all(p.b < 50 for p in got.passages)  # no passage names a left-out area


def test_serve_cuts_a_long_state_to_its_payload_limit(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
) -> None:
    # A small max_payload_bytes stands for a long session's state: a robot whose rooms
    # alternate gets a closed submap per room; its state soon outgrows 2,000 bytes.
    limit = 2000
    # One decision a frame: coalesced frames under load would join rooms and close fewer submaps.
    service = serve(
        "--method",
        "paper",
        "--max-batch-frames",
        "1",
        "--limits-max-payload-bytes",
        str(limit),
        metrics=True,
    )
    session = client_session(service.endpoint)
    rooms = [list(range(70_000 * (r + 1), 70_000 * (r + 1) + 40)) for r in range(2)]  # 5 B ids
    with RobotPublisher(fleet_name, "walker", session=session) as robot:
        assert robot.wait_for_service(20.0), service.log()
        seq = 0
        for visit in range(16):
            for _ in range(20):
                robot.publish(rooms[visit % 2], stamp_s=seq * 0.1, seq=seq)
                seq += 1
    key = keys.state(fleet_name, "walker")
    box: list[SessionState] = []

    def cut_state() -> bool:
        for reply in session.get(key, timeout=2.0):
            if reply.ok is None:
                continue
            data = reply.ok.payload.to_bytes()
            assert len(data) <= limit
            found = decode(data, SessionState, replace(DEFAULT_LIMITS, max_payload_bytes=limit))
            if not found.open and found.frames_applied == seq:
                box.append(found)
                return True
        return False

    wait_until(cut_state, 60.0, "the closed session's state", service.log)
    found = box[0]
    assert found.transitions >= 10
    kept = [s.id for s in found.closed_submaps]
    assert 0 < len(kept) < found.transitions  # cut, and the newest kept
    assert kept == list(range(found.transitions - len(kept), found.transitions))
    assert metric_value(service.metrics(), "lessmap_replies_cut_total", kind="state") >= 1
    assert service.log().count("state reply over the wire limits") == 1  # once per robot
    assert service.terminate() == 0


@pytest.mark.parametrize("limit", [64, 200])
def test_a_state_that_cannot_fit_still_sends_its_smallest_form(limit: int) -> None:
    limits = replace(DEFAULT_LIMITS, max_payload_bytes=limit)
    payload, dropped = fit_state(state(5, 100), limits)
    assert dropped == 5  # every closed submap left out: nothing smaller to send
    assert decode(payload, SessionState).closed_submaps == []

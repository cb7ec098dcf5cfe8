"""``lessmap view`` and ``lessmap record`` on a live service: what Foxglove would receive."""

from __future__ import annotations

import json
import struct
import time
from typing import TYPE_CHECKING, Any

import pytest

from tests.conftest import free_port, wait_until
from tests.viz.conftest import (
    FRAMES_PER_ROOM,
    ROOMS,
    publish_walks,
    start_command,
    stop_command,
)

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from tests.conftest import ServeProcess

SUBPROTOCOL = "foxglove.sdk.v1"
TOPICS = {"/lessmap/scene", "/lessmap/transitions", "/lessmap/state", "/lessmap/tf"}
ROBOTS = ["amr1", "amr2"]
FRAMES = FRAMES_PER_ROOM * ROOMS
#: The doorway label of each robot's first transition (protobuf keeps strings verbatim).
DOOR_LABEL = {robot: f"{robot} 0→1".encode() for robot in ROBOTS}


def connect_ws(port: int) -> Any:
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    deadline = time.monotonic() + 30
    while True:
        try:
            return connect(
                f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol(SUBPROTOCOL)], open_timeout=5
            )
        except OSError:
            assert time.monotonic() < deadline, "the view server never listened"
            time.sleep(0.1)


def subscribe_all(ws: Any, topics: set[str]) -> tuple[dict[int, str], dict[str, dict[str, Any]]]:
    """Wait until ``topics`` are advertised and subscribe to every channel.

    Returns:
        The topic of each subscription id, and each topic's advertised channel.
    """
    channels: dict[int, dict[str, Any]] = {}
    deadline = time.monotonic() + 20
    while not topics <= {c["topic"] for c in channels.values()}:
        assert time.monotonic() < deadline, f"advertised: {channels}"
        message = ws.recv(timeout=5)
        if isinstance(message, str):
            op = json.loads(message)
            if op["op"] == "advertise":
                channels.update({c["id"]: c for c in op["channels"]})
    subscriptions = [{"id": i, "channelId": cid} for i, cid in enumerate(channels)]
    ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
    by_topic = {c["topic"]: c for c in channels.values()}
    return {i: channels[cid]["topic"] for i, cid in enumerate(channels)}, by_topic


def receive(ws: Any, topic_of: dict[int, str], into: dict[str, list[bytes]]) -> None:
    """Receive one message (1 s at most); keep it by topic if it is message data."""
    try:
        message = ws.recv(timeout=1)
    except TimeoutError:
        return
    if isinstance(message, bytes) and message[0] == 0x01:  # MessageData
        sub_id, _log_time = struct.unpack_from("<IQ", message, 1)
        into.setdefault(topic_of[sub_id], []).append(message[13:])


def test_view_serves_the_fleet_over_the_foxglove_websocket_protocol(
    serve: Callable[..., ServeProcess], fleet_name: str, tmp_path: Path
) -> None:
    import lessmap_client

    service = serve("--memory-only", "--max-batch-frames", "1")
    port = free_port()
    view = start_command(
        tmp_path,
        "view",
        *("view", "--fleet", fleet_name, "-e", service.endpoint, "--port", str(port)),
        *("--covgraph", "amr1"),
    )
    try:
        with connect_ws(port) as ws:
            assert ws.subprotocol == SUBPROTOCOL
            topic_of, by_topic = subscribe_all(ws, TOPICS | {"/lessmap/covgraph"})
            with lessmap_client.connect(service.endpoint, timeout_s=20) as conn:
                assert conn.wait_for_service(20)
                publish_walks(conn, fleet_name, ROBOTS)
                received: dict[str, list[bytes]] = {}

                def applied_everywhere() -> bool:
                    for payload in received.get("/lessmap/state", [])[::-1]:
                        rows = {r["robot"]: r for r in json.loads(payload)["robots"]}
                        return all(
                            rows.get(r, {}).get("frames_applied") == FRAMES
                            and rows[r]["transitions"] >= 1
                            for r in ROBOTS
                        )
                    return False

                deadline = time.monotonic() + 30
                while not (
                    applied_everywhere()
                    and len(received.get("/lessmap/transitions", [])) >= len(ROBOTS)
                    and any(DOOR_LABEL["amr2"] in p for p in received.get("/lessmap/scene", []))
                    and received.get("/lessmap/covgraph")
                ):
                    assert time.monotonic() < deadline, {k: len(v) for k, v in received.items()}
                    receive(ws, topic_of, received)
    finally:
        summary = stop_command(view)

    assert by_topic["/lessmap/state"]["encoding"] == "json"
    assert by_topic["/lessmap/transitions"]["schemaName"] == "foxglove.Log"
    assert by_topic["/lessmap/scene"]["schemaName"] == "foxglove.SceneUpdate"
    logs = b"".join(received["/lessmap/transitions"])
    for robot in ROBOTS:  # protobuf keeps strings verbatim
        assert f"{robot}: area 0 -> area 1 from seq {FRAMES_PER_ROOM}".encode() in logs
    scenes = b"".join(received["/lessmap/scene"])
    assert b"amr1/trajectory" in scenes
    assert b"amr1/covgraph" in b"".join(received["/lessmap/covgraph"])
    assert summary["port"] == port
    assert summary["transitions"] == len(ROBOTS)
    assert summary["frames"] == len(ROBOTS) * FRAMES


def receive_until(
    ws: Any, topic_of: dict[int, str], into: dict[str, list[bytes]], done: Callable[[], bool]
) -> None:
    """Receive on ``ws`` until ``done()`` (20 s at most)."""
    deadline = time.monotonic() + 20
    while not done():
        assert time.monotonic() < deadline, {k: len(v) for k, v in into.items()}
        receive(ws, topic_of, into)


def test_late_clients_get_the_picture_and_no_client_sees_a_log_entry_twice(
    serve: Callable[..., ServeProcess], fleet_name: str, tmp_path: Path
) -> None:
    import lessmap_client

    service = serve("--memory-only", "--max-batch-frames", "1")
    port = free_port()
    view = start_command(
        tmp_path,
        "view",
        *("view", "--fleet", fleet_name, "-e", service.endpoint, "--port", str(port)),
    )
    log = tmp_path / "view.log"
    early: dict[str, list[bytes]] = {}
    joined: dict[str, list[bytes]] = {}
    alone: dict[str, list[bytes]] = {}
    try:
        wait_until(lambda: "following fleet" in log.read_text(), 30, "the view to subscribe")
        with connect_ws(port) as first:
            first_topics, _ = subscribe_all(first, TOPICS)
            with lessmap_client.connect(service.endpoint, timeout_s=20) as conn:
                assert conn.wait_for_service(20)
                publish_walks(conn, fleet_name, ROBOTS)
                receive_until(
                    first,
                    first_topics,
                    early,
                    lambda: len(early.get("/lessmap/transitions", [])) >= len(ROBOTS),
                )
            # A second client joins while the first one follows the log: it gets the scene,
            # and the first one must not get the recent entries again.
            with connect_ws(port) as second:
                second_topics, _ = subscribe_all(second, TOPICS)
                receive_until(second, second_topics, joined, lambda: "/lessmap/tf" in joined)
                quiet = time.monotonic() + 2  # a re-send would arrive within milliseconds
                while time.monotonic() < quiet:
                    receive(first, first_topics, early)
                    receive(second, second_topics, joined)
        # The run is over and nobody is connected: a client alone gets the recent entries.
        with connect_ws(port) as third:
            third_topics, _ = subscribe_all(third, TOPICS)
            receive_until(
                third,
                third_topics,
                alone,
                lambda: bool(
                    alone.get("/lessmap/scene")
                    and len(alone.get("/lessmap/transitions", [])) >= len(ROBOTS)
                    and alone.get("/lessmap/tf")
                    and any(b"amr2" in p for p in alone.get("/lessmap/state", []))
                ),
            )
    finally:
        summary = stop_command(view)

    assert len(early["/lessmap/transitions"]) == len(ROBOTS)  # each entry once
    assert "/lessmap/transitions" not in joined
    for robot in ROBOTS:
        assert f"{robot}/trajectory".encode() in joined["/lessmap/scene"][0]
        assert f"{robot}/trajectory".encode() in alone["/lessmap/scene"][0]
        assert DOOR_LABEL[robot] in alone["/lessmap/scene"][0]
    logs = b"".join(alone["/lessmap/transitions"])
    for robot in ROBOTS:
        assert f"{robot}: area 0 -> area 1 from seq {FRAMES_PER_ROOM}".encode() in logs
    assert b"map" in alone["/lessmap/tf"][0]
    rows = json.loads(alone["/lessmap/state"][-1])["robots"]  # the table comes every second
    assert [r["robot"] for r in rows] == ROBOTS
    assert summary["scene re-sends"] >= 3
    assert summary["log re-sends withheld"] == 1  # the second client's
    assert summary["transitions re-sent"] == len(ROBOTS)  # the third client's
    assert summary["transitions"] == len(ROBOTS)
    assert "no frames readable" not in summary


def test_a_view_that_cannot_read_frames_says_so(
    serve: Callable[..., ServeProcess], fleet_name: str, tmp_path: Path
) -> None:
    import zenoh

    from lessmap_client.session import open_session
    from lessmap_schemas import codec, keys
    from lessmap_schemas.messages import SubmapSummary, Transition

    service = serve("--memory-only")
    view = start_command(
        tmp_path,
        "view",
        *("view", "--fleet", fleet_name, "-e", service.endpoint, "--port", "0"),
    )
    log = tmp_path / "view.log"
    transition = Transition(
        fleet=fleet_name,
        robot="amr1",
        session="s1",
        incarnation=0,
        seq=20,
        boundary_seq=15,
        stamp_s=1.0,
        reason="DISCONNECTED",
        ncut=None,
        lambda2=None,
        closed=SubmapSummary(id=0, first_seq=0, last_seq=14, frame_count=15, features=[1]),
        opened=SubmapSummary(id=1, first_seq=15, last_seq=20, frame_count=6, features=[2]),
        boundary_features=[],
        area=1,
        left_area=0,
        revisit=False,
        batch_frames=1,
        instance="i",
        partition=0,
        epoch=1,
    )
    try:
        wait_until(lambda: "following fleet" in log.read_text(), 30, "the view to subscribe")
        # A transition on the bus but no frame: what a view sees when the site's access
        # control lets it read the transitions and not the frames.
        session = open_session([service.endpoint], timeout_s=20)
        try:
            session.put(
                keys.transitions(fleet_name, "amr1"),
                codec.encode(transition),
                encoding=zenoh.Encoding(codec.encoding(transition)),
            )
            wait_until(
                lambda: "no frame reached the view" in log.read_text(), 30, "the view to say it"
            )
        finally:
            session.close()
    finally:
        summary = stop_command(view)

    (line,) = [x for x in log.read_text().splitlines() if "no frame reached the view" in x]
    assert f"cannot read {keys.KEY_PREFIX}/{fleet_name}/*/frames/*" in line
    assert summary["transitions"] == 1
    assert summary["no frames readable"] == 1
    assert "frames" not in summary


def test_a_view_started_before_the_service_waits_for_it(
    serve: Callable[..., ServeProcess], fleet_name: str, tmp_path: Path
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # A service can take tens of seconds to listen on a loaded machine: wait longer.
    view = start_command(
        tmp_path,
        "view",
        *("view", "--fleet", fleet_name, "-e", endpoint, "--port", "0"),
        *("--connect-timeout", "60"),
    )
    log = tmp_path / "view.log"
    try:
        wait_until(
            lambda: f"waiting for the lessmap service on {endpoint} (up to 60 s" in log.read_text(),
            30,
            "the view to say it waits",
        )
        time.sleep(2)  # longer than any retry interval: the view keeps waiting
        assert view.poll() is None
        serve("--memory-only", "-l", endpoint)
        wait_until(lambda: "following fleet" in log.read_text(), 45, "the view to connect")
    finally:
        summary = stop_command(view)
    assert summary["fleet"] == fleet_name
    assert log.read_text().count("waiting for the lessmap service") == 1


def test_a_view_with_no_service_gives_up_in_one_line(fleet_name: str, tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    view = start_command(
        tmp_path,
        "view",
        *("view", "--fleet", fleet_name, "-e", endpoint, "--port", "0"),
        *("--connect-timeout", "1"),
    )
    try:
        out, _ = view.communicate(timeout=30)
    finally:
        if view.poll() is None:
            view.kill()
            view.wait(5)
    assert view.returncode == 1
    assert out == ""
    lines = (tmp_path / "view.log").read_text().strip().splitlines()
    assert lines == [
        f"lessmap view: no Zenoh router answered at {endpoint} (-e/--connect): is `lessmap "
        "serve` or `lessmap router` running there? (waited 1 s)"
    ]


def test_record_writes_the_same_channels_to_mcap(
    serve: Callable[..., ServeProcess], fleet_name: str, tmp_path: Path
) -> None:
    from mcap.reader import make_reader

    import lessmap_client
    from lessmap.viz.scene import places_of
    from lessmap_client.fleet_areas import FleetParams

    service = serve("--memory-only", "--max-batch-frames", "1")
    out = tmp_path / "fleet.mcap"
    record = start_command(
        tmp_path,
        "record",
        "record",
        "--fleet",
        fleet_name,
        "-e",
        service.endpoint,
        "--mcap",
        str(out),
        "--shared-features",
    )
    log = tmp_path / "record.log"
    try:
        wait_until(lambda: "following fleet" in log.read_text(), 30, "the recorder to subscribe")
        with lessmap_client.connect(service.endpoint, timeout_s=20) as conn:
            assert conn.wait_for_service(20)
            publish_walks(conn, fleet_name, ROBOTS)

            def applied() -> bool:
                states = {s.robot: s.frames_applied for s in conn.states(fleet_name)}
                return all(states.get(r) == FRAMES for r in ROBOTS)

            wait_until(applied, 30, "every frame to be applied")
            wait_until(
                lambda: log.read_text().count("submap 0 -> 1") == len(ROBOTS),
                30,
                "the recorder to receive the transitions",
            )
            states = conn.states(fleet_name)
            places = places_of(
                states, conn.fleet_area_graph(fleet_name, FleetParams(shared_features=True))
            )
            time.sleep(1.5)  # one more state table after the last transition
    finally:
        summary = stop_command(record)

    counts: dict[str, int] = {}
    payloads: dict[str, list[bytes]] = {}
    with out.open("rb") as handle:
        reader = make_reader(handle)
        topics = {c.topic: c for c in reader.get_summary().channels.values()}  # type: ignore[union-attr]
        for _schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            payloads.setdefault(channel.topic, []).append(message.data)
    assert set(topics) == TOPICS
    assert topics["/lessmap/state"].message_encoding == "json"
    assert counts["/lessmap/transitions"] == len(ROBOTS) == summary["transitions"]
    assert counts["/lessmap/scene"] == summary["scene updates"] >= 1
    assert counts["/lessmap/state"] == summary["state tables"] >= 1
    final = json.loads(payloads["/lessmap/state"][-1])
    assert [r["robot"] for r in final["robots"]] == ROBOTS
    assert {r["frames_applied"] for r in final["robots"]} == {FRAMES}
    assert {r["submap"] for r in final["robots"]} == {1}
    # --shared-features: each robot's place, its current area's fleet area, as the SDK's
    # merge names it. The service's default method, areas: the walk's second room is area 1.
    assert {(r["method"], r["area"]) for r in final["robots"]} == {("areas", 1)}
    assert sorted(places) == ROBOTS
    assert {r["robot"]: r["place"] for r in final["robots"]} == places
    scenes = b"".join(payloads["/lessmap/scene"])
    assert b"amr1/trajectory" in scenes
    assert DOOR_LABEL["amr2"] in scenes


def test_record_refuses_to_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lessmap.cli.app import main

    existing = tmp_path / "x.mcap"
    existing.write_bytes(b"keep")
    argv = ["record", "--fleet", "f", "--mcap", str(existing), "-e", "tcp/127.0.0.1:1"]
    assert main([*argv, "--connect-timeout", "0.1"]) == 1
    assert capsys.readouterr().err.strip() == (
        f"lessmap record: {existing} exists (give --overwrite to replace it)"
    )
    assert existing.read_bytes() == b"keep"

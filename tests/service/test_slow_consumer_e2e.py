"""A fleet app that never reads: the other robots' frames are all applied and published.

Real processes on loopback: ``lessmap serve`` in router mode, an app in its own process
whose callback on every lessmap key never returns, and in this process a robot streaming
DLR, a noisy session filling the app's link, and a fleet client. Latency is the
benchmark's (``benchmarks/isolation.py``); here: nothing lost, nothing different.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap.files.frames import read_frames
from lessmap_client import FleetClient, RobotPublisher
from lessmap_schemas import keys
from tests.conftest import dataset
from tests.service.test_serve_e2e import (
    as_record,
    drain,
    offline_transitions,
    start_service,
    wait_closed,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from tests.conftest import ServeProcess

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]

# The app: Zenoh's receiving thread is stuck in its callback from the first sample on.
SLOW_APP = """
import sys, threading, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", '["%s"]' % sys.argv[1])
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
session.declare_subscriber(sys.argv[2], lambda _sample: threading.Event().wait())
print("ready", flush=True)
threading.Event().wait()
"""
NOISE_BYTES = 64 * 1024  # a put only the app subscribes to; 200 of them fill its link


@pytest.fixture
def slow_app() -> Iterator[Callable[[str], subprocess.Popen[bytes]]]:
    started: list[subprocess.Popen[bytes]] = []

    def start(endpoint: str) -> subprocess.Popen[bytes]:
        args = [sys.executable, "-c", SLOW_APP, endpoint, f"{keys.KEY_PREFIX}/**"]
        app = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        started.append(app)
        assert app.stdout is not None
        assert app.stdout.readline().strip() == b"ready"
        return app

    yield start
    for app in started:
        app.kill()
        app.wait(10)
        if app.stdout is not None:
            app.stdout.close()


def test_an_app_that_never_reads_delays_nobody_into_loss(
    serve: Callable[..., ServeProcess],
    client_session: Callable[[str], zenoh.Session],
    fleet_name: str,
    slow_app: Callable[[str], subprocess.Popen[bytes]],
) -> None:
    frames = list(read_frames(dataset("dlr.frames.jsonl")))
    expected = offline_transitions(frames)["0"]
    service = start_service(serve)
    session = client_session(service.endpoint)  # waits for the router to listen
    app = slow_app(service.endpoint)
    noise_session = client_session(service.endpoint)
    stop = threading.Event()
    noise_key = f"{keys.KEY_PREFIX}/{fleet_name}/noise/blob"

    def noise() -> None:
        # As a robot puts (BLOCK): without the routers' drop, the router would wait for the
        # app's full link and hold up whatever it forwards behind it.
        while not stop.is_set():
            noise_session.put(
                noise_key, bytes(NOISE_BYTES), congestion_control=zenoh.CongestionControl.BLOCK
            )
            stop.wait(0.005)

    noisy = threading.Thread(target=noise, daemon=True)
    with FleetClient(fleet_name, session=session) as client:
        with RobotPublisher(fleet_name, "dlr", session=session) as robot:
            assert robot.wait_for_service(20.0), service.log()
            noisy.start()
            try:
                for frame in frames:
                    robot.publish(frame.features, stamp_s=frame.stamp_s, seq=frame.seq)
            finally:
                stop.set()
                noisy.join(30)
        state = wait_closed(client, fleet_name, "dlr", len(frames))
        got = drain(client)
    assert app.poll() is None, "the app was still there, still not reading"
    assert (state.frames_applied, state.frames_missing, state.frames_rejected) == (
        len(frames),
        0,
        0,
    )
    assert [as_record(t) for t in got] == expected
    assert service.terminate() == 0

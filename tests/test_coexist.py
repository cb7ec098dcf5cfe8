"""Sharing a machine with ROS 2: ``lessmap serve`` joins a router already on its endpoint.

Tests never take the real 7447: the endpoint the service would take is a free port here, and
a plain Zenoh router in the test process stands in for rmw_zenohd.
"""

from __future__ import annotations

import socket
import threading
from typing import TYPE_CHECKING

import pytest
import zenoh

from lessmap.config.coexist import join_existing_router, listening
from lessmap.config.settings import load_settings
from lessmap.errors import ConfigError
from lessmap_schemas import keys
from tests.conftest import free_port

if TYPE_CHECKING:
    from collections.abc import Iterator


def test_a_router_on_the_endpoint_is_joined_as_a_client(router: str) -> None:
    settings = load_settings(memory_only=True)
    assert settings.embedded
    joined = join_existing_router(settings, router)
    assert (joined.mode, joined.connect, joined.listen) == ("client", (router,), ())
    assert not joined.embedded
    assert joined.memory_only  # every other setting kept


def test_a_free_endpoint_or_a_zenoh_option_changes_nothing(router: str) -> None:
    settings = load_settings()
    assert join_existing_router(settings, f"tcp/127.0.0.1:{free_port()}") is settings
    chosen = load_settings(mode="client", connect=[router])
    assert join_existing_router(chosen, router) is chosen  # the user chose: never overridden


def test_a_taken_listen_port_or_an_absent_router_is_one_line_before_start(router: str) -> None:
    taken = load_settings(mode="router", listen=[router])
    with pytest.raises(ConfigError, match=r"cannot listen on .* -l/--listen"):
        join_existing_router(taken, router)
    nobody = f"tcp/127.0.0.1:{free_port()}"
    alone = load_settings(mode="client", connect=[nobody], connect_timeout=0.5)
    with pytest.raises(ConfigError, match=f"no Zenoh router answered at {nobody}"):
        join_existing_router(alone)


@pytest.fixture
def not_zenoh() -> Iterator[str]:
    """A TCP server on loopback that accepts connections and closes them (not Zenoh)."""
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(0.1)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"tcp/127.0.0.1:{server.getsockname()[1]}"
    stop.set()
    thread.join(5)
    server.close()


def test_a_port_taken_by_something_else_says_what_to_do(not_zenoh: str) -> None:
    assert listening(not_zenoh)
    with pytest.raises(ConfigError) as raised:
        join_existing_router(load_settings(), not_zenoh, timeout_s=1.0)
    message = str(raised.value)
    assert "\n" not in message
    assert message.startswith(f"{not_zenoh} is taken by a program that is not a Zenoh router")
    assert "lessmap serve -l tcp/127.0.0.1:7448" in message


ROS2_KEYS = [
    "0/**",  # rmw_zenoh data keys: <domain_id>/<topic>/<type>/<hash>
    "232/**",
    "@ros2_lv/**",  # rmw_zenoh liveliness tokens (graph cache)
    "0/amr7/detections/apriltag_msgs::msg::dds_::AprilTagDetectionArray_/*",
]


@pytest.mark.parametrize("ros", ROS2_KEYS)
def test_lessmap_keys_never_meet_ros2_keys(ros: str) -> None:
    ours = [
        keys.frames("f", "r"),
        keys.frames_of_partition(3),
        keys.transitions(),
        keys.errors(),
        keys.state("f", "r"),
        keys.submaps("f", "r"),
        keys.instances(),
        keys.health(),
        keys.checkpoints(),
        keys.service_errors(),
        f"{keys.KEY_PREFIX}/**",
    ]
    for key in ours:
        assert not zenoh.KeyExpr(key).intersects(zenoh.KeyExpr(ros)), (key, ros)

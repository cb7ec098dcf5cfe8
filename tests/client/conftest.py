"""Fixtures of the client tests."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest
import zenoh

from tests.conftest import free_port

if TYPE_CHECKING:
    from collections.abc import Iterator


@pytest.fixture
def router() -> Iterator[str]:
    """A plain Zenoh router in the test process, on a free loopback port; its endpoint.

    Tests play the service's part on it with sessions of their own (liveliness tokens,
    queryables, forged puts), so the SDK meets a real network.
    """
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    with zenoh.open(conf):
        yield endpoint

"""Client SDK of lessmap: robots publish frames, fleet apps receive transitions.

```python
import lessmap_client

with lessmap_client.connect() as conn:  # tcp/127.0.0.1:7447
    with conn.subscribe_transitions("warehouse") as sub:
        for t in sub:
            print(t.robot, t.closed.id, "->", t.opened.id)
```

``lessmap_client.aio`` is the same API for asyncio; ``lessmap_client.testing`` has an
in-process ``FakeBus`` for testing fleet apps and robot code without a router.
"""

from __future__ import annotations

import logging
from importlib.metadata import version

from lessmap_client.connection import Connection, connect
from lessmap_client.errors import SessionClosedError
from lessmap_client.fleet import FleetClient
from lessmap_client.robot import RobotPublisher, RobotStatus, close_all, new_session_id
from lessmap_client.session import DEFAULT_ENDPOINT, open_session, wait_for_service
from lessmap_client.subscription import Subscription

__version__ = version("lessmap-client")  # one source: the repository's VERSION file

__all__ = [
    "DEFAULT_ENDPOINT",
    "Connection",
    "FleetClient",
    "RobotPublisher",
    "RobotStatus",
    "SessionClosedError",
    "Subscription",
    "__version__",
    "close_all",
    "connect",
    "new_session_id",
    "open_session",
    "wait_for_service",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())

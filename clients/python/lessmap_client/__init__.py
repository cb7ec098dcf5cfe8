"""Client SDK of lessmap: robots publish frames, fleet apps receive transitions."""

from __future__ import annotations

import logging
from importlib.metadata import version

from lessmap_client.fleet import FleetClient
from lessmap_client.robot import RobotPublisher, new_session_id
from lessmap_client.session import DEFAULT_ENDPOINT, open_session, wait_for_service

__version__ = version("lessmap-client")  # one source: the repository's VERSION file

__all__ = [
    "DEFAULT_ENDPOINT",
    "FleetClient",
    "RobotPublisher",
    "__version__",
    "new_session_id",
    "open_session",
    "wait_for_service",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())

"""lessmap: online environment segmentation for robot fleets (LESS-mapping over Zenoh)."""

from __future__ import annotations

import logging

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

"""lessmap: online environment segmentation for robot fleets (LESS-mapping over Zenoh)."""

from __future__ import annotations

import logging
from importlib.metadata import version

__version__ = version("lessmap")  # one source: the VERSION file at the repository root

logging.getLogger(__name__).addHandler(logging.NullHandler())

"""Client SDK of lessmap: robots publish frames, fleet apps receive transitions."""

from __future__ import annotations

import logging

logging.getLogger(__name__).addHandler(logging.NullHandler())

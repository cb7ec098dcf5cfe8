"""``python -m lessmap``."""

from __future__ import annotations

import sys

from lessmap.cli.app import main

sys.exit(main())

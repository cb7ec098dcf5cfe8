"""Build hook: pin the sibling distributions to this one's version (all three move together).

The service depends on the SDK and the contract, the SDK on the contract; a wheel of one
version must never install next to another version of its siblings, since the wire contract
changes with them. The version is the repository's ``VERSION`` file, read by each
``pyproject.toml``; this hook writes ``NAME==VERSION`` for every sibling the hook's config
lists under ``siblings``, ahead of its other ``dependencies``.
"""

from __future__ import annotations

from typing import Any

from hatchling.metadata.plugin.interface import MetadataHookInterface


class SiblingPins(MetadataHookInterface):
    """Dependencies: the siblings at exactly this version, then the config's own list."""

    PLUGIN_NAME = "custom"

    def update(self, metadata: dict[str, Any]) -> None:
        """Set ``dependencies`` from the hook's ``siblings`` and ``dependencies``."""
        version = metadata["version"]
        pins = [f"{name}=={version}" for name in self.config.get("siblings", [])]
        metadata["dependencies"] = [*pins, *self.config.get("dependencies", [])]

"""Service settings: one model, filled from defaults < config file < environment < flags.

Environment variables are ``LESSMAP_<FIELD>`` (nested: ``LESSMAP_LIMITS__MAX_PAYLOAD_BYTES``).
Zenoh's own configuration is never re-modelled here: it is a JSON5 file handed to
``zenoh.Config.from_file`` plus the ``--connect/--listen/--mode`` overrides.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_settings import BaseSettings, SettingsConfigDict

from lessmap.core import PROFILES, PartitionParams, SeedMode
from lessmap.errors import ConfigError
from lessmap_schemas.keys import validate_name
from lessmap_schemas.limits import (
    MAX_DETAIL_LEN,
    MAX_FEATURE_ID,
    MAX_NAME_LEN,
    MAX_SEQ,
    WireLimits,
)

#: Where the embedded router listens when no Zenoh option is given.
EMBEDDED_ENDPOINT = "tcp/127.0.0.1:7447"


class LimitSettings(BaseModel):
    """Wire limits the service enforces on every inbound message (see schemas/README.md)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # Receiver policy: raise or lower freely.
    max_payload_bytes: int = Field(1_048_576, ge=64)
    max_features_per_frame: int = Field(4096, ge=1)
    max_list_len: int = Field(100_000, ge=1)
    # Format bounds of v1: may only be lowered (schemas/README.md §8).
    max_name_len: int = Field(MAX_NAME_LEN, ge=1, le=MAX_NAME_LEN)
    max_seq: int = Field(MAX_SEQ, ge=1, le=MAX_SEQ)
    max_feature_id: int = Field(MAX_FEATURE_ID, ge=1, le=MAX_FEATURE_ID)
    max_detail_len: int = Field(MAX_DETAIL_LEN, ge=1, le=MAX_DETAIL_LEN)

    def wire_limits(self) -> WireLimits:
        """Return the codec's limits."""
        return WireLimits(**self.model_dump())


class ServiceSettings(BaseSettings):
    """Everything ``lessmap serve`` can be told; every field has a working default."""

    model_config = SettingsConfigDict(
        env_prefix="LESSMAP_", env_nested_delimiter="__", frozen=True, extra="forbid"
    )

    # -- partitioning (Eq. 4) --
    profile: Literal["laser", "stereo", "monocular"] = "laser"
    ncut_min: float | None = Field(None, ge=0.0, description="overrides the profile")
    lambda2_min: float | None = Field(None, ge=0.0, description="overrides the profile")
    seed_mode: SeedMode = SeedMode.SEED
    min_frames_between: int = Field(0, ge=0)
    min_cluster_size: int = Field(1, ge=1)

    # -- sessions --
    session_idle_timeout_s: float = Field(300.0, gt=0.0)
    max_sessions: int = Field(10_000, ge=1)
    max_nodes_per_session: int = Field(20_000, ge=2)
    max_batch_frames: int = Field(256, ge=1, description="1 = decide at every frame")

    # -- receive path --
    # One shard by default: shards are threads sharing one GIL, and a second one measured
    # slower, not faster (docs/BENCHMARKS.md); more shards only isolate robots from each other.
    workers: int = Field(1, ge=1, le=64, description="shards; a robot always maps to one")
    queue_depth: int = Field(50_000, ge=1, description="pending messages per shard")
    # A shard that wakes on a nearly empty queue may wait this long for more frames, so one
    # round serves several. Off by default: at 200 robots x 10 Hz, 2 ms saved 12 % of the
    # service's CPU but doubled the median latency; at saturation it changed nothing, since
    # rounds are large anyway (docs/BENCHMARKS.md). For CPU-tight hosts.
    batch_linger_ms: float = Field(
        0.0, ge=0.0, le=100.0, description="wait for more frames after a wake-up (ms)"
    )
    # Static sharding across instances: this instance serves the robots whose frames key
    # hashes (crc32) to shard_index modulo shard_count; run one instance per index.
    shard_index: int = Field(0, ge=0)
    shard_count: int = Field(1, ge=1, le=1024)

    # -- outputs --
    transition_cache: int = Field(
        64, ge=1, description="transitions kept per robot for late joiners"
    )
    error_rate_per_s: float = Field(
        5.0, gt=0.0, description="error events per robot, error code and second"
    )
    error_burst: int = Field(20, ge=1)
    instance: str = Field(default_factory=lambda: f"{socket.gethostname()[:40]}-{os.getpid()}")
    shutdown_grace_s: float = Field(
        2.0, ge=0.0, description="on stop, keep taking frames until quiet, at most this long"
    )
    metrics_port: int | None = Field(None, ge=0, le=65535)
    metrics_addr: str = "127.0.0.1"

    # -- zenoh --
    zenoh_config: Path | None = None
    mode: Literal["peer", "client", "router"] | None = None
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()

    limits: LimitSettings = LimitSettings()

    @field_validator("instance")
    @classmethod
    def _instance_is_a_name(cls, value: str) -> str:
        # Instances appear as key chunks (liveliness token, health key): same rule as robots.
        cleaned = "".join(c if c.isascii() and (c.isalnum() or c in "_.-") else "-" for c in value)[
            :64
        ]
        return validate_name(cleaned.lstrip(".-") or "lessmap", "instance")

    @model_validator(mode="after")
    def _shard_in_range(self) -> ServiceSettings:
        if self.shard_index >= self.shard_count:
            msg = f"shard_index {self.shard_index} must be below shard_count {self.shard_count}"
            raise ValueError(msg)
        return self

    @property
    def embedded(self) -> bool:
        """True when no Zenoh option was given: open our own router on loopback."""
        return (
            self.zenoh_config is None and self.mode is None and not self.connect and not self.listen
        )

    def partition_params(self) -> PartitionParams:
        """Return the core's parameters for every session of this service."""
        ncut_min, lambda2_min = PROFILES[self.profile]
        return PartitionParams(
            ncut_min=self.ncut_min if self.ncut_min is not None else ncut_min,
            lambda2_min=self.lambda2_min if self.lambda2_min is not None else lambda2_min,
            seed_mode=self.seed_mode,
            min_frames_between=self.min_frames_between,
            min_cluster_size=self.min_cluster_size,
        )


def load_settings(config_file: Path | None = None, **overrides: Any) -> ServiceSettings:
    """Build the settings: defaults < JSON config file < ``LESSMAP_*`` environment < overrides.

    Raises:
        ConfigError: a value is invalid or the config file cannot be read (one-line message).
    """
    file_values: object = {}
    if config_file is not None:
        try:
            file_values = json.loads(config_file.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            msg = f"cannot read config file {config_file}: {exc}"
            raise ConfigError(msg) from exc
        if not isinstance(file_values, dict):
            msg = f"config file {config_file}: expected a JSON object"
            raise ConfigError(msg)
    try:
        # Environment beats the file: pydantic-settings gives init kwargs precedence, so the
        # file's values go in as defaults of a subclass-free merge below.
        from_env = ServiceSettings()
        assert isinstance(file_values, dict)
        merged = _deep_merge(_deep_merge(file_values, _explicit(from_env)), overrides)
        return ServiceSettings(**merged)
    except (ValidationError, ValueError) as exc:
        msg = f"invalid setting: {_first_error(exc)}"
        raise ConfigError(msg) from exc


def _explicit(settings: ServiceSettings) -> dict[str, Any]:
    """Return only the fields the environment actually set (nested ones too)."""
    return settings.model_dump(exclude_unset=True)


def _deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Return ``base`` updated by ``over``; nested dicts merge key by key."""
    merged = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _first_error(exc: Exception) -> str:
    if isinstance(exc, ValidationError):
        error = exc.errors()[0]
        where = ".".join(str(p) for p in error["loc"])
        return f"{where}: {error['msg']} (got {error.get('input')!r})"
    return str(exc)

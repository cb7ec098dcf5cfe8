"""Service settings: one model, filled from defaults < config file < environment < flags.

Every field of ``ServiceSettings`` is at once a key of the config file (JSON, or TOML by its
``.toml`` suffix), an environment variable ``LESSMAP_<FIELD>`` (nested:
``LESSMAP_LIMITS__MAX_PAYLOAD_BYTES``) and a ``serve`` flag ``--<field>`` (nested:
``--limits-max-payload-bytes``): adding a field adds all three. The precedence is the order of
the pydantic-settings sources (``settings_customise_sources``), not a hand-made merge.

Zenoh's own configuration is never re-modelled here: it is a JSON5 file handed to
``zenoh.Config.from_file`` plus the ``--connect/--listen/--mode`` overrides.
"""

from __future__ import annotations

import json
import os
import re
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    SettingsError,
)
from pydantic_settings.sources import InitSettingsSource

from lessmap.cli.flags import (
    Flag,
    FlagSpec,
    add_flags,
    describe_path,
    flag_specs,
    given,
    lookup,
)
from lessmap.config.partitioning import (
    DEFAULT_METHOD,
    TITLE as PARTITION_TITLE,
    PartitionSettings,
)
from lessmap.errors import ConfigError, setting_error
from lessmap_client.cli_options import (
    CONNECT_HELP,
    DEFAULT_CONNECT_TIMEOUT_S,
    LISTEN_HELP,
    TIMEOUT_HELP,
    ZENOH_CONFIG_HELP,
    add_zenoh_options,
    mode_help,
)
from lessmap_schemas.keys import validate_name
from lessmap_schemas.limits import (
    MAX_DETAIL_LEN,
    MAX_FEATURE_ID,
    MAX_NAME_LEN,
    MAX_SEQ,
    WireLimits,
)

if TYPE_CHECKING:
    import argparse
    from collections.abc import Mapping

#: Where the embedded router listens when no Zenoh option is given.
EMBEDDED_ENDPOINT = "tcp/127.0.0.1:7447"
#: Prefix of every environment variable of the service.
ENV_PREFIX = "LESSMAP_"

_MODES = ("client", "peer", "router")
#: The settings that are Zenoh options: their flags are the shared grammar's.
ZENOH_FIELDS = frozenset({"zenoh_config", "mode", "connect", "listen", "connect_timeout"})


class LimitSettings(BaseModel):
    """Wire limits the service enforces on every inbound message (see schemas/README.md)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # Receiver policy: raise or lower freely.
    max_payload_bytes: int = Field(1_048_576, ge=64, description="largest encoded message")
    max_features_per_frame: int = Field(4096, ge=1, description="most features in one frame")
    max_list_len: int = Field(100_000, ge=1, description="longest list in a message to clients")
    # Format bounds of v1: may only be lowered (schemas/README.md §8).
    max_name_len: int = Field(
        MAX_NAME_LEN, ge=1, le=MAX_NAME_LEN, description="longest name (may only be lowered)"
    )
    max_seq: int = Field(MAX_SEQ, ge=1, le=MAX_SEQ, description="largest seq (may only be lowered)")
    max_feature_id: int = Field(
        MAX_FEATURE_ID,
        ge=1,
        le=MAX_FEATURE_ID,
        description="largest feature ID (may only be lowered)",
    )
    max_detail_len: int = Field(
        MAX_DETAIL_LEN,
        ge=1,
        le=MAX_DETAIL_LEN,
        description="longest error detail (may only be lowered)",
    )

    def wire_limits(self) -> WireLimits:
        """Return the codec's limits."""
        return WireLimits(**self.model_dump())


class ServiceSettings(BaseSettings, PartitionSettings):
    """Everything ``lessmap serve`` can be told; every field has a working default.

    The partitioning fields (profile, ncut_min, lambda2_min, seed_mode, min_frames_between,
    min_cluster_size) come from ``PartitionSettings``, shared with the offline commands.
    """

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX, env_nested_delimiter="__", frozen=True, extra="forbid"
    )

    config: Annotated[Path | None, Flag(metavar="FILE")] = Field(
        None, description="JSON or TOML file of settings, below the environment and flags"
    )

    # -- sessions --
    session_idle_timeout_s: Annotated[float, Flag("--idle-timeout")] = Field(
        300.0,
        gt=0.0,
        description="seconds before an idle session is evicted (closed when memory-only)",
    )
    method: Literal["paper", "areas", "rooms"] = Field(
        DEFAULT_METHOD,
        description="segmentation of new sessions: areas = confirmed splits, revisits named; "
        "rooms = a windowed cut for buildings, revisits named (on the wire: areas); "
        "paper = LESS-mapping as published (a session keeps the method it started with)",
    )
    # Rule 3b of the areas method reads a stamp gap as blindness only in a stream that
    # leaves out its empty frames; elsewhere a gap is a stall or a loss (AreaParams).
    empty_frames_omitted: Annotated[tuple[str, ...], Flag(metavar="FLEET")] = Field(
        (),
        description="fleets whose robots leave out their empty frames (a frame only when "
        "something is seen): with the areas method their stamp gaps count as blind frames; "
        "* for every fleet (a session keeps what it started with)",
    )
    max_sessions: int = Field(10_000, ge=1, description="open sessions at most")
    max_nodes_per_session: int = Field(20_000, ge=2, description="CovGraph nodes per session")
    max_batch_frames: int = Field(
        256, ge=1, description="frames coalesced per decision under load (1 = decide every frame)"
    )

    # -- work budgets (docs/BENCHMARKS.md, "Noisy neighbours") --
    # A frame of k features makes k(k-1)/2 pair updates, a decision costs in proportion to
    # the CovGraph's edges: these bound the work, where max_nodes_per_session bounds nodes.
    max_pairs_per_frame: int = Field(
        200_000,
        ge=1,
        description="feature pairs one frame may update, k(k-1)/2 (about 630 features); k "
        "counts the features kept (areas: at most max_features_kept)",
    )
    max_edges_per_session: int = Field(
        1_000_000,
        ge=1,
        description="CovGraph edges per session (one decision ~0.3 s at it; a dense graph above "
        "400 nodes counts its matrix bytes at 24 B an edge when that is more)",
    )
    max_edges_total: int = Field(
        20_000_000, ge=1, description="CovGraph edges summed over the sessions in memory"
    )
    new_sessions_per_s_per_fleet: float = Field(
        200.0, gt=0.0, description="new sessions a fleet may open per second (token bucket)"
    )
    new_sessions_burst: int = Field(
        2000, ge=1, description="new sessions a fleet may open in a burst"
    )
    # Deciding at every frame is the paper's loop; a shard that falls behind decides once per
    # robot turn instead: a decision costs more than a frame's counting, so deciding per
    # frame under a backlog only deepens it (figures: docs/tuning/service.md).
    coalesce_after_ms: float = Field(
        50.0,
        ge=0.0,
        description="a frame that waited this long in the queue makes its robot's pending "
        "frames share one decision (ms)",
    )
    fair_quantum: int = Field(
        5_000_000,
        ge=1000,
        description="work per robot and scheduling round, in pair updates (fair scheduling)",
    )
    # A decision holds its worker for as long as it takes; a robot whose decisions take long
    # is served by a second worker per shard, so the others never wait for one
    # (docs/design/heavy-robots.md).
    heavy_decision_ms: float = Field(
        20.0,
        ge=0.0,
        description="a robot whose decisions are estimated to take longer than this (ms) "
        "moves to its shard's heavy lane, a worker of its own; 0 = no heavy lane",
    )

    # -- durable sessions --
    # Checkpoints go to <state_dir>/sessions.sqlite3. A restarted instance resumes each
    # session at its checkpoint and asks the robots' publication caches for the frames after
    # it, so the rule is: a robot's cache (RobotPublisher cache, 1000 frames by default) must
    # hold the frames of one checkpoint interval plus the downtime, at its frame rate.
    state_dir: Path | None = Field(
        None,
        description="folder of the session checkpoint store "
        "(default: $XDG_STATE_HOME/lessmap, else ~/.local/state/lessmap)",
    )
    memory_only: bool = Field(
        False, description="keep sessions in memory only: a restart loses them"
    )
    checkpoint_every_frames: int = Field(
        100, ge=1, description="checkpoint a session after this many applied frames"
    )
    # 10 s: at 10 Hz the same spacing as checkpoint_every_frames; a checkpoint rewrites the
    # session's whole state, so shorter intervals cost the worker (docs/tuning/service.md).
    checkpoint_interval_s: float = Field(
        10.0, gt=0.0, description="or after this many seconds with new frames"
    )
    catchup_max_frames: int = Field(
        1000, ge=1, description="frames asked of each robot's cache when catching up"
    )
    catchup_wait_s: float = Field(
        2.0,
        gt=0.0,
        le=60.0,
        description="frames after a gap wait this long at most for the robot's cache",
    )
    state_retention_s: float = Field(
        7 * 24 * 3600.0, gt=0.0, description="drop stored sessions not updated for this long"
    )
    state_max_bytes: int = Field(
        1 << 30, ge=1 << 20, description="size bound of the store; oldest idle sessions go first"
    )

    # -- processes and receive path --
    # Each worker is an instance process of its own (its own GIL), sharing the partitions
    # with the others through the instances' ownership and hand-over (runtime/supervisor.py).
    workers: int | None = Field(
        None,
        ge=1,
        le=256,
        description="instance processes on this host, sharing the partitions (default: the "
        "usable cores; 1 = one process, no supervisor)",
    )
    # One shard by default: shards are threads sharing one GIL, so more shards isolate robots
    # from each other but do not add throughput (docs/tuning/service.md).
    shards: int = Field(
        1, ge=1, le=64, description="shards (threads) per worker; a robot maps to one"
    )
    queue_depth: int = Field(50_000, ge=1, description="pending messages per shard")
    # A shard that wakes on a nearly empty queue may wait this long for more frames, so one
    # round serves several. Off by default: it saves CPU but costs latency; for CPU-tight
    # hosts (docs/tuning/service.md).
    batch_linger_ms: float = Field(
        0.0,
        ge=0.0,
        le=100.0,
        description="after waking on a quiet queue, wait for more frames (ms)",
    )
    # Several instances: partitions are owned by rendezvous hashing over the live instances
    # (schemas/README.md section 2a); nothing to configure but distinct instance names.
    # One subscription to every partition's frames, filtered by ownership, or one per owned
    # partition: Zenoh's cost per sample grows with the subscriptions it matches, but "all"
    # takes every instance's frames; past a handful of instances "partitions" costs less.
    frames_subscription: Literal["all", "partitions"] = Field(
        "all",
        description="subscribe to every partition's frames (filtered by ownership) or only "
        "to the owned partitions'",
    )
    fence_after_s: float = Field(
        2.0,
        gt=0.0,
        le=60.0,
        description="a stall of the process longer than this drops every partition (fencing)",
    )
    handover_fetch_s: float = Field(
        2.0,
        gt=0.0,
        le=60.0,
        description="when taking a partition over, wait this long at most for its checkpoints",
    )
    # A joining instance waits for the live former owner to say it has handed each partition
    # over (its final checkpoints written) before fetching them: fetched earlier, they miss
    # what the former owner still decided, e.g. a session it closed. A former owner that
    # does not answer (frozen, or a version without the hand-shake) costs this much once.
    handover_release_s: float = Field(
        3.0,
        gt=0.0,
        le=60.0,
        description="when joining, wait this long at most for the former owners to release "
        "the partitions this instance takes from them",
    )

    # -- outputs --
    transition_cache: int = Field(
        64, ge=1, description="transitions kept per robot for late joiners"
    )
    error_rate_per_s: float = Field(
        5.0, gt=0.0, description="error events per robot, error code and second"
    )
    error_burst: int = Field(20, ge=1, description="error events in a burst")
    instance: str = Field(
        default_factory=lambda: f"{socket.gethostname()[:40]}-{os.getpid()}",
        description="instance name (default: host-pid)",
    )
    shutdown_grace_s: float = Field(
        2.0, ge=0.0, description="on stop, keep taking frames until quiet, at most this long"
    )
    metrics_port: int | None = Field(
        None, ge=0, le=65535, description="serve Prometheus /metrics on this port"
    )
    metrics_addr: str = Field("127.0.0.1", description="address of /metrics")

    # -- zenoh: flags of the shared grammar (``lessmap_client.cli_options``), not derived --
    zenoh_config: Path | None = Field(None, description=ZENOH_CONFIG_HELP)
    mode: Literal["peer", "client", "router"] | None = Field(None, description=mode_help(_MODES))
    connect: tuple[str, ...] = Field((), description=CONNECT_HELP)
    listen: tuple[str, ...] = Field((), description=LISTEN_HELP)
    connect_timeout: float = Field(
        DEFAULT_CONNECT_TIMEOUT_S, gt=0.0, allow_inf_nan=False, description=TIMEOUT_HELP
    )

    limits: LimitSettings = LimitSettings()

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """Return the sources, first wins: flags (init kwargs), environment, config file."""
        del dotenv_settings, file_secret_settings
        flags = init_settings.init_kwargs if isinstance(init_settings, InitSettingsSource) else {}
        path = flags.get("config") or _environ().get(ENV_PREFIX + "CONFIG") or None
        return (init_settings, env_settings, ConfigFileSource(settings_cls, path))

    @field_validator("empty_frames_omitted")
    @classmethod
    def _fleets_are_names(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for fleet in value:
            if fleet != "*":
                validate_name(fleet, "fleet")
        return value

    def omits_empty_frames(self, fleet: str) -> bool:
        """Whether the fleet's robots leave out their empty frames (``empty_frames_omitted``)."""
        return "*" in self.empty_frames_omitted or fleet in self.empty_frames_omitted

    @field_validator("instance")
    @classmethod
    def _instance_is_a_name(cls, value: str) -> str:
        # Instances appear as key chunks (liveliness token, health key): same rule as robots.
        cleaned = "".join(c if c.isascii() and (c.isalnum() or c in "_.-") else "-" for c in value)[
            :64
        ]
        return validate_name(cleaned.lstrip(".-") or "lessmap", "instance")

    def resolved_state_dir(self) -> Path:
        """The state directory: the setting, else the XDG state home's ``lessmap`` folder."""
        if self.state_dir is not None:
            return self.state_dir
        xdg = os.environ.get("XDG_STATE_HOME")
        base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".local" / "state"
        return base / "lessmap"

    @property
    def embedded(self) -> bool:
        """True when no Zenoh option was given: open our own router on loopback."""
        return (
            self.zenoh_config is None and self.mode is None and not self.connect and not self.listen
        )


class ConfigFileSource(PydanticBaseSettingsSource):
    """The settings file: JSON, or TOML when its name ends in ``.toml``."""

    def __init__(self, settings_cls: type[BaseSettings], path: str | Path | None) -> None:
        super().__init__(settings_cls)
        self.path = None if path is None else Path(path)

    def get_field_value(self, field: Any, field_name: str) -> tuple[Any, str, bool]:
        """Unused: ``__call__`` returns the whole file."""
        del field
        return None, field_name, False

    def __call__(self) -> dict[str, Any]:
        """Return the file's values (nothing when no file is named)."""
        return {} if self.path is None else read_config_file(self.path)


def read_config_file(path: Path) -> dict[str, Any]:
    """Return the object a JSON or TOML settings file holds.

    Raises:
        ConfigError: the file cannot be read, is not JSON/TOML or holds no object.
    """
    try:
        text = path.read_text(encoding="utf-8")
        if path.suffix == ".toml":
            import tomllib

            values: object = tomllib.loads(text)
        else:
            values = json.loads(text)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        msg = f"cannot read config file {path}: {exc}"
        raise ConfigError(msg) from exc
    if not isinstance(values, dict):
        msg = f"config file {path}: expected a JSON object"
        raise ConfigError(msg)
    return values


def load_settings(config_file: Path | None = None, **overrides: Any) -> ServiceSettings:
    """Build the settings: defaults < config file < ``LESSMAP_*`` environment < overrides.

    Raises:
        ConfigError: a value is invalid or the config file cannot be read (one-line message).
    """
    if config_file is not None:
        overrides["config"] = config_file
    return build_settings(overrides, {})


def build_settings(values: Mapping[str, Any], flags: Mapping[str, str]) -> ServiceSettings:
    """Build the settings with ``values`` on top (flags, or a caller's overrides).

    Args:
        values: the highest-precedence values, nested as the model is.
        flags: for each dotted field path in ``values``, the flag that set it (for messages).

    Raises:
        ConfigError: one line naming the invalid setting and where its value came from.
    """
    try:
        return ServiceSettings(**values)
    except ValidationError as exc:
        error = exc.errors()[0]
        path = tuple(error["loc"])
        where = describe_path(path) or "settings"
        msg = f"invalid setting {where} = {error.get('input')!r} from "
        source = _source_of(path, values, flags)
        msg += f"{source}: {error['msg'].removeprefix('Value error, ')}"
        raise setting_error(msg, error["type"], from_flag=source.startswith("flag ")) from None
    except SettingsError as exc:
        # The environment holds a value that is not JSON where a list or object is expected.
        match = re.search(r'field "(\w+)"', str(exc))
        field = match.group(1) if match else "?"
        msg = f"invalid setting {field} from environment {ENV_PREFIX}{field.upper()}: "
        msg += 'expected JSON, e.g. ["tcp/10.0.0.5:7447"] or {"max_seq": 1000}'
        raise ConfigError(msg) from None


def _source_of(path: tuple[Any, ...], values: Mapping[str, Any], flags: Mapping[str, str]) -> str:
    """Name where the value at ``path`` came from: flag, environment, config file or default."""
    for depth in range(len(path), 0, -1):
        found, _ = lookup(values, path[:depth])
        if found:
            key = describe_path(path[:depth])
            return f"flag {flags[key]}" if key in flags else "the caller"
    environ = _environ()
    for depth in range(len(path), 0, -1):
        name = ENV_PREFIX + "__".join(str(p) for p in path[:depth]).upper()
        if name in environ:
            return f"environment {name}"
    config = values.get("config") or environ.get(ENV_PREFIX + "CONFIG")
    if config:
        try:
            found, _ = lookup(read_config_file(Path(config)), path[:1])
        except ConfigError:
            found = False
        if found:
            return f"config file {config}"
    return "the defaults"


def _environ() -> dict[str, str]:
    """Return the environment with upper-case names (pydantic-settings ignores case)."""
    return {name.upper(): value for name, value in os.environ.items()}


def add_settings_flags(parser: argparse.ArgumentParser) -> list[FlagSpec]:
    """Add one ``serve`` flag per settings field (nested limits too); return their specs.

    The Zenoh fields take the flags every networked command has (``add_zenoh_options``).
    """
    specs = add_flags(parser, PartitionSettings, title=PARTITION_TITLE, env_prefix=ENV_PREFIX)
    partition = {spec.dest for spec in specs}
    specs += add_flags(
        parser,
        ServiceSettings,
        title="service (flags beat LESSMAP_* environment beats --config FILE)",
        env_prefix=ENV_PREFIX,
        exclude=frozenset(partition | ZENOH_FIELDS),
    )
    embedded = f"default: none, an embedded router on {EMBEDDED_ENDPOINT}"
    notes = {
        "connect": f"{embedded}; env {ENV_PREFIX}CONNECT",
        "listen": f"{embedded}; env {ENV_PREFIX}LISTEN",
        "mode": f"default: router when no Zenoh option is given, else Zenoh's peer; "
        f"env {ENV_PREFIX}MODE",
        "zenoh_config": f"env {ENV_PREFIX}ZENOH_CONFIG",
        "connect_timeout": f"client mode; default: {DEFAULT_CONNECT_TIMEOUT_S:g}; "
        f"env {ENV_PREFIX}CONNECT_TIMEOUT",
    }
    add_zenoh_options(parser, modes=_MODES, notes=notes, suppress_defaults=True)
    specs += [s for s in flag_specs(ServiceSettings) if s.dest in ZENOH_FIELDS]
    return specs


def settings_from_args(
    args: argparse.Namespace,
    specs: list[FlagSpec],
    extra: Mapping[str, Any] | None = None,
    extra_flags: Mapping[str, str] | None = None,
) -> ServiceSettings:
    """Build the settings from the flags that were given (plus ``extra`` values from other flags).

    Raises:
        ConfigError: one line naming the invalid setting and its source.
    """
    values, flags = given(args, specs)
    values.update(extra or {})
    flags.update(extra_flags or {})
    return build_settings(values, flags)

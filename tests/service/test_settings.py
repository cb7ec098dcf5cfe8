"""Service settings (defaults < JSON file < LESSMAP_* environment < overrides) and the Zenoh
configuration built from them. Environment variables are set with pytest's ``monkeypatch``."""

from __future__ import annotations

import json
import os
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from lessmap.cli.flags import FlagSpec, flag_specs
from lessmap.config.settings import EMBEDDED_ENDPOINT, LimitSettings, ServiceSettings, load_settings
from lessmap.core import PartitionParams, SeedMode
from lessmap.errors import ConfigError
from lessmap.runtime.zenoh_config import service_config
from lessmap_schemas.keys import validate_name

if TYPE_CHECKING:
    import zenoh


@pytest.fixture(autouse=True)
def clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """No LESSMAP_* variable of the outer environment leaks into a test."""
    for name in list(os.environ):
        if name.upper().startswith("LESSMAP_"):
            monkeypatch.delenv(name)


def write_config(tmp_path: Path, values: object) -> Path:
    path = tmp_path / "lessmap.json"
    path.write_text(json.dumps(values), encoding="utf-8")
    return path


def config_error(config_file: Path | None = None, **overrides: Any) -> str:
    with pytest.raises(ConfigError) as caught:
        load_settings(config_file, **overrides)
    message = str(caught.value)
    assert "\n" not in message, message
    return message


def json_at(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


# -- sources and precedence ------------------------------------------------------------------


def test_defaults() -> None:
    settings = load_settings()

    assert settings.profile == "laser"
    assert (settings.ncut_min, settings.lambda2_min) == (None, None)
    assert settings.seed_mode is SeedMode.SEED
    assert settings.shards == 1
    assert settings.max_batch_frames == 256
    assert settings.batch_linger_ms == 0.0  # latency first; lingering is opt-in
    assert settings.max_sessions == 10_000
    assert settings.limits.max_features_per_frame == 4096
    assert settings.limits.max_payload_bytes == 1_048_576
    assert (settings.mode, settings.connect, settings.listen) == (None, (), ())
    assert settings.zenoh_config is None
    assert settings.embedded
    assert validate_name(settings.instance, "instance") == settings.instance
    assert settings.partition_params() == PartitionParams(ncut_min=0.25, lambda2_min=0.2)


def test_environment_variables(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LESSMAP_PROFILE", "monocular")
    monkeypatch.setenv("LESSMAP_LIMITS__MAX_FEATURES_PER_FRAME", "10")
    monkeypatch.setenv("LESSMAP_CONNECT", '["tcp/127.0.0.1:7448"]')

    settings = load_settings()

    assert settings.profile == "monocular"
    assert settings.limits.max_features_per_frame == 10
    assert settings.limits.max_payload_bytes == 1_048_576  # its sibling keeps the default
    assert settings.connect == ("tcp/127.0.0.1:7448",)
    assert not settings.embedded
    assert settings.limits.wire_limits().max_features_per_frame == 10


def test_precedence_defaults_file_environment_overrides(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = write_config(
        tmp_path, {"shards": 3, "queue_depth": 7, "error_burst": 9, "profile": "stereo"}
    )
    monkeypatch.setenv("LESSMAP_QUEUE_DEPTH", "70")
    monkeypatch.setenv("LESSMAP_ERROR_BURST", "90")

    settings = load_settings(config, error_burst=900)

    assert settings.max_sessions == 10_000  # default: nobody set it
    assert settings.shards == 3  # file beats default
    assert settings.profile == "stereo"
    assert settings.queue_depth == 70  # environment beats file
    assert settings.error_burst == 900  # overrides beat everything


def test_nested_environment_variable_keeps_the_file_siblings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Precedence holds per field: a LESSMAP_LIMITS__X variable sets limits.x only; the
    # other limits keep the file's values, not the defaults.
    config = write_config(tmp_path, {"limits": {"max_payload_bytes": 4096}})
    monkeypatch.setenv("LESSMAP_LIMITS__MAX_FEATURES_PER_FRAME", "10")

    settings = load_settings(config)

    assert settings.limits.max_features_per_frame == 10
    assert settings.limits.max_payload_bytes == 4096


def test_file_values_without_environment(tmp_path: Path) -> None:
    config = write_config(
        tmp_path,
        {"limits": {"max_payload_bytes": 4096}, "listen": ["tcp/127.0.0.1:7449"], "shards": 4},
    )
    settings = load_settings(config)
    assert settings.limits.max_payload_bytes == 4096
    assert settings.listen == ("tcp/127.0.0.1:7449",)
    assert settings.shards == 4
    assert not settings.embedded


# -- invalid input ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"shards": 0}, "shards"),
        ({"shards": 65}, "shards"),
        ({"profile": "sonar"}, "profile"),
        ({"max_batch_frames": 0}, "max_batch_frames"),
        ({"batch_linger_ms": -1.0}, "batch_linger_ms"),
        ({"batch_linger_ms": 500.0}, "batch_linger_ms"),
        ({"session_idle_timeout_s": 0.0}, "session_idle_timeout_s"),
        ({"seed_mode": "sometimes"}, "seed_mode"),
        ({"mode": "broker"}, "mode"),
        ({"metrics_port": 70_000}, "metrics_port"),
        ({"limits": {"max_name_len": 65}}, "max_name_len"),
    ],
    ids=lambda v: None if isinstance(v, str) else json.dumps(v),
)
def test_invalid_override_names_the_field(overrides: dict[str, Any], field: str) -> None:
    message = config_error(**overrides)
    assert message.startswith("invalid setting")
    assert field in message


def test_invalid_environment_value_names_the_field(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LESSMAP_SHARDS", "many")
    assert "shards" in config_error()


def test_unknown_key_in_the_config_file(tmp_path: Path) -> None:
    message = config_error(write_config(tmp_path, {"wokers": 3}))
    assert "wokers" in message


def test_invalid_value_in_the_config_file(tmp_path: Path) -> None:
    message = config_error(write_config(tmp_path, {"profile": "sonar"}))
    assert "profile" in message


def test_bad_json_config_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{"shards": 3,', encoding="utf-8")
    message = config_error(path)
    assert str(path) in message


def test_config_file_must_hold_an_object(tmp_path: Path) -> None:
    message = config_error(write_config(tmp_path, [1, 2]))
    assert "object" in message


def test_missing_config_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.json"
    assert str(path) in config_error(path)


# -- derived values --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("profile", "expected"),
    [("laser", (0.25, 0.2)), ("stereo", (0.25, 0.2)), ("monocular", (0.1, 0.1))],
)
def test_partition_params_follow_the_profile(profile: str, expected: tuple[float, float]) -> None:
    params = load_settings(profile=profile).partition_params()
    assert (params.ncut_min, params.lambda2_min) == expected


def test_partition_params_overrides() -> None:
    settings = load_settings(
        profile="monocular",
        ncut_min=0.3,
        seed_mode="fresh",
        min_frames_between=4,
        min_cluster_size=2,
    )
    assert settings.partition_params() == PartitionParams(
        ncut_min=0.3,
        lambda2_min=0.1,  # from the profile
        seed_mode=SeedMode.FRESH,
        min_frames_between=4,
        min_cluster_size=2,
    )
    only_lambda = load_settings(lambda2_min=0.0).partition_params()
    assert (only_lambda.ncut_min, only_lambda.lambda2_min) == (0.25, 0.0)


@pytest.mark.parametrize(
    "zenoh_option",
    [
        {"connect": ("tcp/127.0.0.1:7448",)},
        {"listen": ("tcp/127.0.0.1:7448",)},
        {"mode": "peer"},
        {"zenoh_config": Path("zenoh.json5")},
    ],
    ids=["connect", "listen", "mode", "zenoh_config"],
)
def test_any_zenoh_option_turns_embedded_off(zenoh_option: dict[str, Any]) -> None:
    assert load_settings().embedded
    assert not load_settings(**zenoh_option).embedded


@pytest.mark.parametrize(
    ("given", "expected"),
    [
        ("robot-host-42", "robot-host-42"),
        ("my host/1:2", "my-host-1-2"),
        ("..hidden", "hidden"),
        ("-.-", "lessmap"),
        ("", "lessmap"),
        ("x" * 100, "x" * 64),
    ],
)
def test_instance_is_sanitized(given: str, expected: str) -> None:
    assert load_settings(instance=given).instance == expected


@pytest.mark.parametrize("given", ["Büro-PC", "ロボット"])
def test_non_ascii_instance_is_sanitized_too(given: str) -> None:
    # str.isalnum() accepts non-ASCII letters and digits; the name rule does not.
    instance = load_settings(instance=given).instance
    assert validate_name(instance, "instance") == instance


# -- Zenoh configuration ---------------------------------------------------------------------


def test_embedded_service_config_is_a_loopback_router() -> None:
    conf = service_config(load_settings())

    assert json_at(conf, "mode") == "router"
    assert json_at(conf, "listen/endpoints") == [EMBEDDED_ENDPOINT]
    assert EMBEDDED_ENDPOINT == "tcp/127.0.0.1:7447"
    assert json_at(conf, "scouting/multicast/enabled") is False
    assert json_at(conf, "timestamping/enabled") is True
    assert json_at(conf, "connect/endpoints") == []


def test_client_service_config_follows_the_settings() -> None:
    settings = load_settings(mode="client", connect=("tcp/127.0.0.1:7448",))
    conf = service_config(settings)

    assert json_at(conf, "mode") == "client"
    assert json_at(conf, "connect/endpoints") == ["tcp/127.0.0.1:7448"]
    assert json_at(conf, "timestamping/enabled") is True  # in every mode
    assert EMBEDDED_ENDPOINT not in str(conf)


@pytest.mark.parametrize(
    ("mode", "listen"),
    [("peer", ["tcp/127.0.0.1:0"]), ("router", ["tcp/127.0.0.1:7447"])],
)
def test_peers_and_routers_stay_on_this_machine_unless_told(mode: str, listen: list[str]) -> None:
    conf = service_config(load_settings(mode=mode, connect=("tcp/127.0.0.1:7448",)))
    assert json_at(conf, "scouting/multicast/enabled") is False
    assert json_at(conf, "listen/endpoints") == listen  # not Zenoh's "every interface"


def test_a_config_that_asks_for_scouting_and_interfaces_gets_them(tmp_path: Path) -> None:
    path = tmp_path / "zenoh.json5"
    path.write_text(
        '{ mode: "peer", scouting: { multicast: { enabled: true } },'
        ' listen: { endpoints: ["tcp/0.0.0.0:7451"] } }',
        encoding="utf-8",
    )
    conf = service_config(load_settings(zenoh_config=path))
    assert json_at(conf, "scouting/multicast/enabled") is True
    assert json_at(conf, "listen/endpoints") == ["tcp/0.0.0.0:7451"]
    override = service_config(load_settings(mode="peer"), ["scouting/multicast/enabled:true"])
    assert json_at(override, "scouting/multicast/enabled") is True


def test_service_config_from_a_zenoh_file(tmp_path: Path) -> None:
    path = tmp_path / "zenoh.json5"
    path.write_text(
        '{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:7450"] } }', encoding="utf-8"
    )
    conf = service_config(load_settings(zenoh_config=path))

    assert json_at(conf, "mode") == "peer"
    assert json_at(conf, "listen/endpoints") == ["tcp/127.0.0.1:7450"]
    assert json_at(conf, "timestamping/enabled") is True


def test_missing_zenoh_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError):
        service_config(load_settings(zenoh_config=tmp_path / "absent.json5"))


def test_cfg_items_are_applied_last() -> None:
    conf = service_config(load_settings(), ["scouting/multicast/enabled:true", 'mode:"peer"'])
    assert json_at(conf, "scouting/multicast/enabled") is True
    assert json_at(conf, "mode") == "peer"


@pytest.mark.parametrize(
    "item", ["no-separator", "no/such/key:1", "mode:{{", "listen/endpoints:42"]
)
def test_bad_cfg_item_is_a_config_error(item: str) -> None:
    with pytest.raises(ConfigError):
        service_config(load_settings(), [item])


def test_every_wire_limit_is_a_setting_and_format_bounds_only_tighten(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("LESSMAP_LIMITS__MAX_SEQ", "1000")
    monkeypatch.setenv("LESSMAP_LIMITS__MAX_LIST_LEN", "10")
    limits = load_settings().limits.wire_limits()
    assert (limits.max_seq, limits.max_list_len, limits.max_detail_len) == (1000, 10, 1024)
    monkeypatch.setenv("LESSMAP_LIMITS__MAX_FEATURE_ID", str(2**64))
    with pytest.raises(ConfigError, match="max_feature_id"):
        load_settings()


# -- one model: every field is a flag, an environment variable and a config key ---------------


def serve_settings(*argv: str) -> Any:
    """Parse ``lessmap serve ARGV`` as the CLI does and build its settings (no service)."""
    from lessmap.cli.app import command_parser
    from lessmap.config.settings import settings_from_args

    parser, _run = command_parser("serve")
    args = parser.parse_args(argv)
    return settings_from_args(args, args.settings_flags)


#: A value of each list setting (a repeatable flag; a JSON list in the environment).
LIST_SAMPLES = {
    "connect": "tcp/127.0.0.1:7500",
    "listen": "tcp/127.0.0.1:7500",
    "empty_frames_omitted": "lab",
}


def other_value(spec: FlagSpec, tmp_path: Path) -> tuple[str, object]:
    """Return a valid value unlike the default, as text and as the field then holds it."""
    field = spec.field
    kind = field.annotation
    default = field.get_default(call_default_factory=True)
    text: str
    if spec.dest == "config":
        path = write_config(tmp_path, {})
        return str(path), path
    if spec.dest in LIST_SAMPLES:
        return LIST_SAMPLES[spec.dest], (LIST_SAMPLES[spec.dest],)
    if spec.dest == "seed_mode":
        return "fresh", SeedMode.FRESH
    if spec.dest == "mode":
        return "peer", "peer"
    if default is None:
        samples = {"metrics_port": 9464, "ncut_min": 0.3, "lambda2_min": 0.1, "workers": 3}
        if spec.dest in samples:
            return str(samples[spec.dest]), samples[spec.dest]
        return "zenoh.json5", Path("zenoh.json5")
    if typing.get_origin(kind) is typing.Literal:
        text = next(str(c) for c in typing.get_args(kind) if c != default)
        return text, text
    if isinstance(default, bool):
        return str(not default).lower(), not default
    if isinstance(default, int | float):
        upper = next((m.le for m in field.metadata if hasattr(m, "le")), None)
        value = default - 1 if upper is not None and default + 1 > upper else default + 1
        return str(value), value
    return "other-value", "other-value"


def value_at(settings: Any, spec: FlagSpec) -> object:
    for part in spec.path:
        settings = getattr(settings, part)
    return settings


SPECS = list(flag_specs(ServiceSettings))


def test_every_field_is_reached() -> None:
    # Nested models contribute their fields; nothing is left without a flag.
    dests = {spec.dest for spec in SPECS}
    assert set(ServiceSettings.model_fields) - {"limits"} <= dests
    assert {f"limits__{name}" for name in LimitSettings.model_fields} <= dests


@pytest.mark.parametrize("spec", SPECS, ids=lambda spec: spec.dest)
def test_every_field_has_a_flag_and_an_environment_variable(
    spec: FlagSpec,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    text, expected = other_value(spec, tmp_path)
    assert value_at(load_settings(), spec) != expected

    if isinstance(expected, bool):  # --name / --no-name
        from_flag = serve_settings(spec.flag if expected else f"--no-{spec.flag[2:]}")
    else:
        from_flag = serve_settings(spec.flag, text)
    assert value_at(from_flag, spec) == expected

    env = f"LESSMAP_{spec.dest.upper()}"
    monkeypatch.setenv(env, json.dumps([text]) if spec.dest in LIST_SAMPLES else text)
    assert value_at(load_settings(), spec) == expected

    with pytest.raises(SystemExit):
        serve_settings("--help")
    assert env in capsys.readouterr().out.replace("\n", " ").replace("  ", "")


@pytest.mark.parametrize(
    "flag",
    [
        "--profile monocular",
        "--ncut-min 0.3",
        "--lambda2-min 0.1",
        "--seed-mode fresh",
        "--shards 2",
        "--metrics-port 9464",
        "--instance edge-1",
        "--fence-after-s 5",
        "--idle-timeout 30",
        "--max-batch-frames 8",
        "--batch-linger-ms 2",
        "-m client",
        "--mode client",
        "-e tcp/10.0.0.5:7447",
        "--connect tcp/10.0.0.5:7447",
        "-l tcp/0.0.0.0:7447",
        "--listen tcp/0.0.0.0:7447",
        "--zenoh-config zenoh.json5",
    ],
)
def test_the_documented_flag_spellings(flag: str) -> None:
    settings = serve_settings(*flag.split())
    assert settings != load_settings()


def test_flags_beat_environment_beat_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    config = write_config(tmp_path, {"shards": 3, "queue_depth": 7, "error_burst": 9})
    monkeypatch.setenv("LESSMAP_QUEUE_DEPTH", "70")
    monkeypatch.setenv("LESSMAP_ERROR_BURST", "90")
    settings = serve_settings("--config", str(config), "--error-burst", "900")
    assert (settings.shards, settings.queue_depth, settings.error_burst) == (3, 70, 900)
    assert settings.config == config


def test_the_config_file_may_come_from_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("LESSMAP_CONFIG", str(write_config(tmp_path, {"shards": 5})))
    assert load_settings().shards == 5
    assert serve_settings("--shards", "6").shards == 6


def test_a_toml_config_file(tmp_path: Path) -> None:
    path = tmp_path / "lessmap.toml"
    path.write_text('shards = 4\nprofile = "stereo"\n[limits]\nmax_seq = 1000\n', "utf-8")
    settings = load_settings(path)
    assert (settings.shards, settings.profile, settings.limits.max_seq) == (4, "stereo", 1000)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("flag", "invalid setting shards = '0' from flag --shards: "),
        ("environment", "invalid setting shards = '0' from environment LESSMAP_SHARDS: "),
        ("file", "invalid setting shards = 0 from config file "),
        ("nested flag", "invalid setting limits.max_seq = '0' from flag --limits-max-seq: "),
        ("nested environment", "from environment LESSMAP_LIMITS__MAX_SEQ: "),
    ],
)
def test_an_invalid_value_is_one_line_naming_setting_and_source(
    source: str, expected: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    argv: list[str] = []
    if source == "flag":
        argv = ["--shards", "0"]
    elif source == "environment":
        monkeypatch.setenv("LESSMAP_SHARDS", "0")
    elif source == "file":
        argv = ["--config", str(write_config(tmp_path, {"shards": 0}))]
    elif source == "nested flag":
        argv = ["--limits-max-seq", "0"]
    else:
        monkeypatch.setenv("LESSMAP_LIMITS__MAX_SEQ", "0")
    with pytest.raises(ConfigError) as caught:
        serve_settings(*argv)
    message = str(caught.value)
    assert "\n" not in message
    assert expected in message


def test_a_list_variable_that_is_not_json_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LESSMAP_CONNECT", "tcp/10.0.0.5:7447")
    message = config_error()
    assert message.startswith("invalid setting connect from environment LESSMAP_CONNECT")


def test_serve_reports_a_bad_setting_in_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from lessmap.cli.app import main

    monkeypatch.setenv("LESSMAP_BATCH_LINGER_MS", "500")
    assert main(["serve"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("lessmap serve: invalid setting batch_linger_ms = '500' from environment")


def test_empty_frames_omitted_names_fleets_or_all() -> None:
    none = serve_settings()
    assert not none.omits_empty_frames("lab")
    some = serve_settings("--empty-frames-omitted", "lab", "--empty-frames-omitted", "yard")
    assert (some.omits_empty_frames("lab"), some.omits_empty_frames("yard")) == (True, True)
    assert not some.omits_empty_frames("lab2")
    every = serve_settings("--empty-frames-omitted", "*")
    assert every.omits_empty_frames("anything")

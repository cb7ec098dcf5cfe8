from __future__ import annotations

import pytest
import zenoh

from lessmap_schemas import ErrorCode, InvalidNameError, WireError, WireLimits, keys, validate_name

GOOD_NAMES = ["a", "Z", "0", "_", "amr-7", "robot_1.2", "_x-", "a..b", "x" * 64, "S_0-." * 12 + "z"]
BAD_NAMES = [
    ("", "empty"),
    ("a/b", "'/'"),
    ("*", "'*'"),
    ("**", "'*'"),
    ("a*", "'*'"),
    ("a$b", "'$'"),
    ("a?b", "'?'"),
    ("a#b", "'#'"),
    ("@a", "'@'"),
    ("a@b", "'@'"),
    (" a", "' '"),
    ("a b", "' '"),
    ("a\n", "'\\n'"),
    ("\t", "'\\t'"),
    (".a", "'.'"),
    ("-a", "'-'"),
    ("r\u00e9sum\u00e9", "'\u00e9'"),
    ("a\x00b", "'\\x00'"),
    ("x" * 65, "longer than 64"),
]


@pytest.mark.parametrize("name", GOOD_NAMES)
def test_valid_names_pass_unchanged(name: str) -> None:
    assert validate_name(name) is name
    assert str(zenoh.KeyExpr(keys.frames("fleet", name))) == keys.frames("fleet", name)


@pytest.mark.parametrize(("name", "explains"), BAD_NAMES, ids=[repr(n)[:20] for n, _ in BAD_NAMES])
def test_invalid_names_raise_with_field_and_character(name: str, explains: str) -> None:
    with pytest.raises(InvalidNameError) as info:
        validate_name(name, "session")
    assert info.value.code is ErrorCode.BAD_NAME
    assert isinstance(info.value, WireError)
    assert isinstance(info.value, ValueError)
    assert "session name" in str(info.value)
    assert explains in str(info.value)
    assert info.value.limit == ("max_name_len" if len(name) > 64 else None)


@pytest.mark.parametrize("value", [5, None, b"robot", ["a"]])
def test_non_str_names_are_rejected(value: object) -> None:
    with pytest.raises(InvalidNameError, match="must be a str"):
        validate_name(value)  # type: ignore[arg-type]


def test_name_length_follows_the_limit() -> None:
    tight = WireLimits(max_name_len=4)
    assert validate_name("abcd", limits=tight) == "abcd"
    with pytest.raises(InvalidNameError) as info:
        validate_name("abcde", "fleet", tight)
    assert info.value.limit == "max_name_len"
    assert "fleet name" in str(info.value)


def test_robot_stream_keys() -> None:
    assert keys.KEY_PREFIX == "lessmap/v1"
    assert keys.WIRE_VERSION == 1
    assert keys.frames("warehouse", "amr-7") == "lessmap/v1/warehouse/amr-7/frames"
    assert keys.transitions("warehouse", "amr-7") == "lessmap/v1/warehouse/amr-7/transitions"
    assert keys.errors("warehouse", "amr-7") == "lessmap/v1/warehouse/amr-7/errors"
    assert keys.state("warehouse", "amr-7") == "lessmap/v1/warehouse/amr-7/state"
    assert keys.submap("warehouse", "amr-7", 3) == "lessmap/v1/warehouse/amr-7/submaps/3"
    assert keys.submaps("warehouse", "amr-7") == "lessmap/v1/warehouse/amr-7/submaps/*"


def test_subscription_helpers_default_to_every_robot() -> None:
    assert keys.transitions() == "lessmap/v1/*/*/transitions"
    assert keys.errors() == "lessmap/v1/*/*/errors"
    assert keys.transitions("warehouse") == "lessmap/v1/warehouse/*/transitions"
    assert keys.frames("*", "*") == "lessmap/v1/*/*/frames"
    assert keys.health() == "lessmap/v1/@/health/*"


@pytest.mark.parametrize("chunk", ["**", "a*", "*a", "$*", "", "a/b"])
def test_only_a_whole_star_chunk_is_a_wildcard(chunk: str) -> None:
    with pytest.raises(InvalidNameError):
        keys.transitions("fleet", chunk)
    with pytest.raises(InvalidNameError):
        keys.frames(chunk, "robot")


def test_service_keys_live_under_the_hermetic_chunk() -> None:
    assert keys.instance_token("lessmap-a1") == "lessmap/v1/@/instances/lessmap-a1"
    assert keys.instances() == "lessmap/v1/@/instances/*"
    assert keys.health("lessmap-a1") == "lessmap/v1/@/health/lessmap-a1"
    with pytest.raises(InvalidNameError):
        keys.instance_token("*")  # a liveliness token must be concrete


@pytest.mark.parametrize("wide", ["lessmap/v1/**", "lessmap/**", "**", "lessmap/v1/*/**"])
def test_fleet_wide_subscriptions_never_see_service_keys(wide: str) -> None:
    service_keys = [keys.instance_token("i-1"), keys.health("i-1"), keys.instances()]
    for key in service_keys:
        assert not zenoh.KeyExpr(wide).intersects(zenoh.KeyExpr(key)), (wide, key)
    assert zenoh.KeyExpr(wide).intersects(zenoh.KeyExpr(keys.frames("f", "r")))


def test_service_patterns_match_their_concrete_keys() -> None:
    pairs = [
        (keys.instances(), keys.instance_token("i-1")),
        (keys.health(), keys.health("i-1")),
        (keys.frames("*", "*"), keys.frames("f", "r")),
        (keys.submaps("*", "*"), keys.submap("f", "r", 12)),
        (keys.transitions(), keys.transitions("f", "r")),
    ]
    for pattern, key in pairs:
        assert zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(key)), (pattern, key)
    assert not zenoh.KeyExpr(keys.frames("*", "*")).intersects(zenoh.KeyExpr(keys.state("f", "r")))


def test_every_key_is_canonical_for_zenoh() -> None:
    made = [
        keys.frames("f", "r"),
        keys.transitions(),
        keys.errors("f"),
        keys.state("f", "r"),
        keys.submap("f", "r", 0),
        keys.submaps("f", "r"),
        keys.instance_token("i"),
        keys.instances(),
        keys.health(),
    ]
    for key in made:
        assert str(zenoh.KeyExpr.autocanonize(key)) == key


@pytest.mark.parametrize("submap_id", [-1, True, 2**53, 1.0, "3"])
def test_submap_ids_are_non_negative_ints(submap_id: object) -> None:
    with pytest.raises(InvalidNameError):
        keys.submap("f", "r", submap_id)  # type: ignore[arg-type]


@pytest.mark.parametrize("stream", keys.ROBOT_STREAMS)
def test_parse_robot_key_round_trips(stream: str) -> None:
    key = f"lessmap/v1/warehouse/amr-7/{stream}"
    assert keys.parse_robot_key(key) == ("warehouse", "amr-7", stream)


@pytest.mark.parametrize(
    "key",
    [
        "lessmap/v2/f/r/frames",
        "other/v1/f/r/frames",
        "lessmap/v1/f/frames",
        "lessmap/v1/f/r/frames/x",
        "lessmap/v1/f/r/telemetry",
        "lessmap/v1/*/r/frames",
        "lessmap/v1/f/**/frames",
        "lessmap/v1//r/frames",
        "lessmap/v1/f/r/submaps/1",
        "lessmap/v1/@/instances/x",
        "",
    ],
)
def test_parse_robot_key_rejects_other_keys(key: str) -> None:
    with pytest.raises(InvalidNameError) as info:
        keys.parse_robot_key(key)
    assert info.value.code is ErrorCode.BAD_NAME


def test_parse_submap_key() -> None:
    assert keys.parse_submap_key(keys.submap("f", "r", 12)) == ("f", "r", 12)
    assert keys.parse_submap_key("lessmap/v1/f/r/submaps/0") == ("f", "r", 0)


@pytest.mark.parametrize("tail", ["01", "-1", "+1", "1.0", "x", "*", "", "\u0661", "9" * 5000])
def test_parse_submap_key_rejects_other_ids(tail: str) -> None:
    with pytest.raises(InvalidNameError):
        keys.parse_submap_key(f"lessmap/v1/f/r/submaps/{tail}")
    with pytest.raises(InvalidNameError):
        keys.parse_submap_key(f"lessmap/v1/f/r/state/{tail}")

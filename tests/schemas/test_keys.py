from __future__ import annotations

import pytest
import zenoh

from lessmap_schemas import (
    ErrorCode,
    InvalidNameError,
    WireError,
    WireLimits,
    keys,
    partition,
    validate_name,
)

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
    assert keys.KEY_PREFIX == "lessmap/v4"
    assert keys.WIRE_VERSION == 4
    # warehouse/amr-7 is in partition 23 (vectors/partition.json pins it).
    assert keys.frames("warehouse", "amr-7") == "lessmap/v4/warehouse/amr-7/frames/23"
    assert keys.transitions("warehouse", "amr-7") == "lessmap/v4/warehouse/amr-7/transitions"
    assert keys.errors("warehouse", "amr-7") == "lessmap/v4/warehouse/amr-7/errors"
    assert keys.state("warehouse", "amr-7") == "lessmap/v4/warehouse/amr-7/state"
    assert keys.submap("warehouse", "amr-7", 3) == "lessmap/v4/warehouse/amr-7/submaps/3"
    assert keys.submaps("warehouse", "amr-7") == "lessmap/v4/warehouse/amr-7/submaps/*"


@pytest.mark.parametrize(("fleet", "robot"), [("f", "r"), ("warehouse", "amr-8"), ("_", "0")])
def test_frames_key_ends_with_the_partition(fleet: str, robot: str) -> None:
    key = keys.frames(fleet, robot)
    assert key.rsplit("/", 1) == [
        f"lessmap/v4/{fleet}/{robot}/frames",
        str(partition.partition_of(fleet, robot)),
    ]
    own = partition.partition_of(fleet, robot)
    for p in range(partition.PARTITIONS):
        pattern = zenoh.KeyExpr(keys.frames_of_partition(p))
        assert pattern.intersects(zenoh.KeyExpr(key)) is (p == own), p


def test_subscription_helpers_default_to_every_robot() -> None:
    assert keys.transitions() == "lessmap/v4/*/*/transitions"
    assert keys.errors() == "lessmap/v4/*/*/errors"
    assert keys.transitions("warehouse") == "lessmap/v4/warehouse/*/transitions"
    assert keys.frames("*", "*") == "lessmap/v4/*/*/frames/*"
    assert keys.frames("warehouse", "*") == "lessmap/v4/warehouse/*/frames/*"
    assert keys.frames_of_partition(0) == "lessmap/v4/*/*/frames/0"
    last = partition.PARTITIONS - 1
    assert keys.frames_of_partition(last) == f"lessmap/v4/*/*/frames/{last}"
    assert keys.health() == "lessmap/v4/@/health/*"


@pytest.mark.parametrize(
    "value", [-1, partition.PARTITIONS, 2**64, True, False, 1.0, "3", "*", None]
)
def test_partition_chunks_are_ints_in_range(value: object) -> None:
    with pytest.raises(InvalidNameError) as info:
        keys.frames_of_partition(value)  # type: ignore[arg-type]
    assert info.value.code is ErrorCode.BAD_NAME
    if value != "*":
        with pytest.raises(InvalidNameError):
            keys.checkpoints(value, "f", "r")  # type: ignore[arg-type]


@pytest.mark.parametrize("chunk", ["**", "a*", "*a", "$*", "", "a/b"])
def test_only_a_whole_star_chunk_is_a_wildcard(chunk: str) -> None:
    with pytest.raises(InvalidNameError):
        keys.transitions("fleet", chunk)
    with pytest.raises(InvalidNameError):
        keys.frames(chunk, "robot")


def test_service_keys_live_under_the_hermetic_chunk() -> None:
    assert keys.instance_token("lessmap-a1") == "lessmap/v4/@/instances/lessmap-a1"
    assert keys.instances() == "lessmap/v4/@/instances/*"
    assert keys.health("lessmap-a1") == "lessmap/v4/@/health/lessmap-a1"
    assert keys.service_errors("lessmap-a1") == "lessmap/v4/@/errors/lessmap-a1"
    assert keys.checkpoints(23, "warehouse", "amr-7") == (
        "lessmap/v4/@/checkpoints/23/warehouse/amr-7"
    )
    assert keys.checkpoints() == "lessmap/v4/@/checkpoints/*/*/*"
    assert keys.checkpoints(5) == "lessmap/v4/@/checkpoints/5/*/*"
    with pytest.raises(InvalidNameError):
        keys.instance_token("*")  # a liveliness token must be concrete


@pytest.mark.parametrize("wide", ["lessmap/v4/**", "lessmap/**", "**", "lessmap/v4/*/**"])
def test_fleet_wide_subscriptions_never_see_service_keys(wide: str) -> None:
    service_keys = [
        keys.instance_token("i-1"),
        keys.health("i-1"),
        keys.instances(),
        keys.service_errors("i-1"),
        keys.checkpoints(3, "f", "r"),
        keys.checkpoints(),
    ]
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
        (keys.frames("f", "*"), keys.frames("f", "r")),
        (keys.checkpoints(), keys.checkpoints(partition.partition_of("f", "r"), "f", "r")),
    ]
    for pattern, key in pairs:
        assert zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(key)), (pattern, key)
    assert not zenoh.KeyExpr(keys.frames("*", "*")).intersects(zenoh.KeyExpr(keys.state("f", "r")))


def test_every_key_is_canonical_for_zenoh() -> None:
    made = [
        keys.frames("f", "r"),
        keys.frames("*", "*"),
        keys.frames_of_partition(7),
        keys.checkpoints(),
        keys.checkpoints(7, "f", "r"),
        keys.service_errors(),
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
    key = f"lessmap/v4/warehouse/amr-7/{stream}" + ("/23" if stream == "frames" else "")
    assert keys.parse_robot_key(key) == ("warehouse", "amr-7", stream)
    made = {"frames": keys.frames, "transitions": keys.transitions, "errors": keys.errors}
    if stream in made:
        assert keys.parse_robot_key(made[stream]("warehouse", "amr-7")) == (
            "warehouse",
            "amr-7",
            stream,
        )


FRAMES = "lessmap/v4/warehouse/amr-7/frames"  # partition 23
BAD_PARTITION_CHUNKS = [
    "",
    "22",
    "24",
    "023",
    "+23",
    "-23",
    "23.0",
    "0x17",
    "*",
    "**",
    "x",
    " 23",
    "23 ",
    "\u0662\u0663",
    str(partition.PARTITIONS),
    "99",
    "-1",
    "9" * 5000,
]


@pytest.mark.parametrize(
    "key",
    [
        FRAMES,  # frames keys end with the partition
        f"{FRAMES}/23/x",
        *[f"{FRAMES}/{chunk}" for chunk in BAD_PARTITION_CHUNKS],
        "lessmap/v4/warehouse/amr-7/transitions/23",
        "lessmap/v4/warehouse/amr-7/state/23",
        "lessmap/v1/warehouse/amr-7/frames",  # superseded
        "lessmap/v1/warehouse/amr-7/frames/23",
        "lessmap/v1/warehouse/amr-7/transitions",
        "other/v3/f/r/transitions",
        "lessmap/v4/f/transitions",
        "lessmap/v4/f/r/telemetry",
        "lessmap/v4/*/r/transitions",
        "lessmap/v4/f/**/transitions",
        "lessmap/v4//r/transitions",
        "lessmap/v4/f/r/submaps/1",
        "lessmap/v4/@/instances/x",
        "lessmap/v4/@/checkpoints/23/warehouse/amr-7",
        "",
    ],
)
def test_parse_robot_key_rejects_other_keys(key: str) -> None:
    with pytest.raises(InvalidNameError) as info:
        keys.parse_robot_key(key)
    assert info.value.code is ErrorCode.BAD_NAME
    assert len(str(info.value)) <= 1024


def test_parse_robot_key_explains_a_wrong_partition() -> None:
    with pytest.raises(InvalidNameError, match="in partition 23"):
        keys.parse_robot_key(f"{FRAMES}/5")


def test_parse_checkpoint_key() -> None:
    key = keys.checkpoints(23, "warehouse", "amr-7")
    assert keys.parse_checkpoint_key(key) == (23, "warehouse", "amr-7")
    for bad in [
        "lessmap/v4/@/checkpoints/5/warehouse/amr-7",
        "lessmap/v4/@/checkpoints/023/warehouse/amr-7",
        "lessmap/v4/@/checkpoints/*/warehouse/amr-7",
        "lessmap/v4/@/checkpoints/23/warehouse/*",
        "lessmap/v4/@/checkpoints/23/warehouse",
        "lessmap/v1/@/checkpoints/23/warehouse/amr-7",
        "lessmap/v4/warehouse/amr-7/frames/23",
    ]:
        with pytest.raises(InvalidNameError):
            keys.parse_checkpoint_key(bad)


def test_parse_submap_key() -> None:
    assert keys.parse_submap_key(keys.submap("f", "r", 12)) == ("f", "r", 12)
    assert keys.parse_submap_key("lessmap/v4/f/r/submaps/0") == ("f", "r", 0)
    with pytest.raises(InvalidNameError):
        keys.parse_submap_key("lessmap/v1/f/r/submaps/0")


@pytest.mark.parametrize("tail", ["01", "-1", "+1", "1.0", "x", "*", "", "\u0661", "9" * 5000])
def test_parse_submap_key_rejects_other_ids(tail: str) -> None:
    with pytest.raises(InvalidNameError):
        keys.parse_submap_key(f"lessmap/v4/f/r/submaps/{tail}")
    with pytest.raises(InvalidNameError):
        keys.parse_submap_key(f"lessmap/v4/f/r/state/{tail}")


def test_released_key_round_trips_and_rejects_others() -> None:
    key = keys.released(23, "inst-a")
    assert key == "lessmap/v4/@/released/23/inst-a"
    assert keys.released() == "lessmap/v4/@/released/*/*"
    assert zenoh.KeyExpr(keys.released()).intersects(zenoh.KeyExpr(key))
    assert keys.parse_released_key(key) == (23, "inst-a")
    for bad in (
        "lessmap/v4/@/released/256/inst-a",
        "lessmap/v4/@/released/023/inst-a",
        "lessmap/v4/@/released/*/inst-a",
        "lessmap/v4/@/released/23",
        "lessmap/v4/@/released/23/a/b",
        "lessmap/v4/@/checkpoints/23/inst-a",
    ):
        with pytest.raises(InvalidNameError):
            keys.parse_released_key(bad)

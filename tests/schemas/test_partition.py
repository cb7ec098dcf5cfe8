"""Partitions and rendezvous owners (contract section 2a) against `vectors/partition.json`.

The vector file is read where it is checked in, as every other client reads it; the spec's
formulas are also recomputed here with hashlib alone, so the file and the package are each
checked against the text of the contract.
"""

from __future__ import annotations

import json
import random
import string
from hashlib import sha256
from pathlib import Path
from typing import Any

import pytest

from lessmap_schemas import keys, partition
from lessmap_schemas.partition import (
    PARTITIONS,
    assignment,
    owner_and_standby,
    partition_of,
    ranking,
    score,
)

VECTORS = Path(__file__).resolve().parents[2] / "schemas" / "vectors"


def vectors() -> dict[str, Any]:
    data: dict[str, Any] = json.loads((VECTORS / "partition.json").read_text(encoding="utf-8"))
    return data


def spec_u64(text: str) -> int:
    """`u64(SHA-256(UTF-8(text))[0..8])`, big-endian, as section 2a writes it."""
    return int.from_bytes(sha256(text.encode("utf-8")).digest()[:8], "big")


def test_vector_file_shape() -> None:
    data = vectors()
    assert data["type"] == "partition"
    assert data["partitions"] == PARTITIONS == 256  # fixed by the contract version
    assert len(data["robots"]) >= 10
    assert len(data["scores"]) >= 6
    assert len(data["rankings"]) >= 10
    assert any(case["ranking"] == [] for case in data["rankings"])  # no token, no owner


@pytest.mark.parametrize("case", vectors()["robots"], ids=lambda c: f"{c['fleet']}/{c['robot']}")
def test_partition_of_matches_the_vectors(case: dict[str, Any]) -> None:
    fleet, robot = case["fleet"], case["robot"]
    assert partition_of(fleet, robot) == case["partition"]
    assert spec_u64(f"{fleet}/{robot}") % PARTITIONS == case["partition"]
    assert keys.frames(fleet, robot).endswith(f"/frames/{case['partition']}")


@pytest.mark.parametrize(
    "case", vectors()["scores"], ids=lambda c: f"{c['instance']}/{c['partition']}"
)
def test_score_matches_the_vectors(case: dict[str, Any]) -> None:
    value = score(case["instance"], case["partition"])
    assert 0 <= value < 2**64
    assert f"{value:016x}" == case["score_hex"]
    assert spec_u64(f"{case['instance']}/{case['partition']}") == int(case["score_hex"], 16)


@pytest.mark.parametrize("case", vectors()["rankings"])
def test_ranking_matches_the_vectors(case: dict[str, Any]) -> None:
    instances, p, expected = case["instances"], case["partition"], case["ranking"]
    assert ranking(p, instances) == expected
    assert ranking(p, reversed(instances)) == expected  # the order of the tokens is irrelevant
    assert ranking(p, [*instances, *instances]) == expected  # so are duplicates
    by_spec = sorted(instances, key=lambda name: (-spec_u64(f"{name}/{p}"), name))
    assert by_spec == expected
    owner, standby = owner_and_standby(p, instances)
    assert owner == (expected[0] if expected else None)
    assert standby == (expected[1] if len(expected) > 1 else None)
    assert assignment(instances)[p] == (owner, standby)


def test_assignment_covers_every_partition() -> None:
    table = assignment(["a", "b", "c"])
    assert sorted(table) == list(range(PARTITIONS))
    assert all(
        owner is not None and standby not in (None, owner) for owner, standby in table.values()
    )
    assert set(assignment([]).values()) == {(None, None)}
    assert set(assignment(["solo"]).values()) == {("solo", None)}


def test_partitions_spread_robots() -> None:
    counts = [0] * PARTITIONS
    for i in range(100 * PARTITIONS):
        counts[partition_of("fleet", f"robot-{i}")] += 1
    assert min(counts) > 50  # 100 expected per partition
    assert partition.PARTITIONS == PARTITIONS


def random_instances(rng: random.Random, count: int) -> set[str]:
    alphabet = string.ascii_lowercase + string.digits + "-_."
    return {
        rng.choice(string.ascii_lowercase) + "".join(rng.choices(alphabet, k=rng.randint(0, 20)))
        for _ in range(count)
    }


@pytest.mark.parametrize("seed", range(50))
def test_a_join_moves_only_the_partitions_the_newcomer_wins(seed: int) -> None:
    rng = random.Random(seed)
    before = random_instances(rng, rng.randint(0, 12))
    newcomer = "new-" + str(seed)
    after = before | {newcomer}
    old, new = assignment(before), assignment(after)
    moved = {p for p in range(PARTITIONS) if old[p][0] != new[p][0]}
    assert moved == {p for p in range(PARTITIONS) if new[p][0] == newcomer}
    if not before:
        assert moved == set(range(PARTITIONS))
    for p in range(PARTITIONS):  # the survivors keep their relative order
        assert [i for i in ranking(p, after) if i != newcomer] == ranking(p, before)


@pytest.mark.parametrize("seed", range(50))
def test_a_leave_moves_only_the_partitions_the_leaver_owned(seed: int) -> None:
    rng = random.Random(1000 + seed)
    before = random_instances(rng, rng.randint(1, 12))
    leaver = rng.choice(sorted(before))
    after = before - {leaver}
    old, new = assignment(before), assignment(after)
    moved = {p for p in range(PARTITIONS) if old[p][0] != new[p][0]}
    assert moved == {p for p in range(PARTITIONS) if old[p][0] == leaver}
    for p in moved:  # the standby takes over
        assert new[p][0] == old[p][1]

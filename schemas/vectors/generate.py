"""Generate the golden vectors in this folder: `python schemas/vectors/generate.py [--check]`.

Every payload is produced by msgpack (or, for the non-minimal integer widths some encoders
write, by `struct`), never typed by hand. Each vector is decoded by `lessmap_schemas` while it
is generated, and the generator stops if the outcome differs from the one declared here, so a
vector file always states what the reference reader does.

File format, one file per message type `<Type>.json`, every payload decoded expecting exactly
that type with default limits:

    {"type": "Frame",
     "valid":   [{"name", "hex", "json": <meaning>, "canonical": <re-encoding gives hex>}],
     "invalid": [{"name", "hex", "code": <ErrorCode>, "limit": <WireLimits field or null>}]}
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:  # run from a checkout without installing the package
    sys.path.insert(0, str(HERE.parent))

import msgpack  # noqa: E402
from fleet_vectors import fleet_area_vectors, partition_vectors  # noqa: E402

from lessmap_schemas import MESSAGE_TYPES, WireError, decode, encode  # noqa: E402
from lessmap_schemas.partition import PARTITIONS  # noqa: E402

DROP = object()
"""Override value that removes a field."""


class Raw(bytes):
    """Pre-encoded msgpack bytes, spliced into a map as they are."""


def pack(value: object, **options: Any) -> bytes:
    """Pack with msgpack, as every writer must: str as str, bytes as bin."""
    data: bytes = msgpack.packb(value, use_bin_type=True, **options)
    return data


def pack_map(fields: dict[str, object]) -> bytes:
    """Pack a map by hand so that a `Raw` value keeps its non-minimal encoding."""
    out = bytearray(msgpack.Packer().pack_map_header(len(fields)))
    for key, value in fields.items():
        out += pack(key) + (value if isinstance(value, Raw) else pack(value))
    return bytes(out)


def pack_pairs(pairs: list[tuple[str, object]]) -> bytes:
    """Pack a map from key/value pairs, repeats included (a dict cannot hold a repeat)."""
    out = bytearray(msgpack.Packer().pack_map_header(len(pairs)))
    for key, value in pairs:
        out += pack(key) + pack(value)
    return bytes(out)


def edit(base: dict[str, object], **changes: object) -> dict[str, object]:
    """Return `base` with fields changed in place, appended, or removed (`DROP`)."""
    out = {**base, **changes}
    return {key: value for key, value in out.items() if value is not DROP}


SUMMARY_A = {"id": 0, "first_seq": 0, "last_seq": 41, "frame_count": 40, "features": [1, 2, 3]}
SUMMARY_B = {"id": 1, "first_seq": 38, "last_seq": 42, "frame_count": 5, "features": [3, 4]}
AREA_A = {"id": 0, "frames": 52, "visits": 2, "first_seq": 0, "last_seq": 90, "features": [1, 2]}
AREA_B = {"id": 2, "frames": 5, "visits": 1, "first_seq": 38, "last_seq": 42, "features": [3, 4]}
PASSAGE = {"a": 0, "b": 2, "a_to_b": 1, "b_to_a": 1, "boundary_features": [[3, 2], [2, 1]]}
BASE: dict[str, dict[str, object]] = {
    "Frame": {
        "type": "Frame",
        "v": 4,
        "session": "run-2024.06_1",
        "seq": 42,
        "stamp_s": 1718000000.25,
        "features": [3, 17, 17, 250, 65536, 4294967296],
        "pose": [1.5, -2.25, 0.75],
    },
    "SessionEnd": {
        "type": "SessionEnd",
        "v": 4,
        "session": "run-2024.06_1",
        "last_seq": 42,
        "stamp_s": 1718000100.5,
    },
    "Transition": {
        "type": "Transition",
        "v": 4,
        "fleet": "warehouse",
        "robot": "amr-7",
        "session": "run-2024.06_1",
        "incarnation": 0,
        "seq": 42,
        "boundary_seq": 38,
        "stamp_s": 1718000000.25,
        "reason": "SPECTRAL",
        "ncut": 0.125,
        "lambda2": 0.03125,
        "closed": SUMMARY_A,
        "opened": SUMMARY_B,
        "boundary_features": [3],
        "area": 1,
        "left_area": 0,
        "revisit": False,
        "batch_frames": 1,
        "instance": "lessmap-a1",
        "partition": 29,
        "epoch": 1718000000123,
    },
    "Error": {
        "type": "Error",
        "v": 4,
        "fleet": "warehouse",
        "robot": "amr-7",
        "session": "run-2024.06_1",
        "code": "SEQ_GAP",
        "detail": "frames 43..45 missing",
        "seq": 46,
        "stamp_s": 1718000001.0,
        "instance": "lessmap-a1",
        "epoch": 1718000000123,
    },
    "SessionState": {
        "type": "SessionState",
        "v": 4,
        "fleet": "warehouse",
        "robot": "amr-7",
        "session": "run-2024.06_1",
        "incarnation": 0,
        "instance": "lessmap-a1",
        "epoch": 1718000000123,
        "open": True,
        "last_seq": 42,
        "frames_applied": 43,
        "frames_duplicate": 2,
        "frames_missing": 0,
        "frames_rejected": 1,
        "transitions": 1,
        "method": "paper",
        "current_area": 1,
        "current_submap": SUMMARY_B,
        "closed_submaps": [SUMMARY_A],
        "nodes": 43,
        "edges": 310,
    },
    "Submap": {
        "type": "Submap",
        "v": 4,
        "fleet": "warehouse",
        "robot": "amr-7",
        "session": "run-2024.06_1",
        "summary": SUMMARY_A,
        "open": False,
    },
    "AreaGraph": {
        "type": "AreaGraph",
        "v": 4,
        "fleet": "warehouse",
        "robot": "amr-7",
        "session": "run-2024.06_1",
        "instance": "lessmap-a1",
        "epoch": 1718000000123,
        "method": "areas",
        "areas": [AREA_A, AREA_B],
        "passages": [PASSAGE],
    },
    "Health": {
        "type": "Health",
        "v": 4,
        "instance": "lessmap-a1",
        "version": "0.1.0",
        "sessions": 12,
        "uptime_s": 3600.5,
        "frames_applied": 123456,
        "partitions": [3, 29, 60],
        "standby": [7],
        "queue_depth": 4,
        "lag_s": 0.015,
    },
}


def wide(value: int) -> Raw:
    """Return `value` as a uint64 (0xcf), the width some C encoders always write."""
    return Raw(b"\xcf" + struct.pack(">Q", value))


Valid = tuple[str, bytes, bool]
"""(name, payload, canonical: whether `encode(decode(payload)) == payload`)."""
Invalid = tuple[str, bytes, str, str | None]
"""(name, payload, error code, limit name)."""


def common(kind: str) -> list[Invalid]:
    """Return the envelope failures every message type shares."""
    base = BASE[kind]
    good = pack(base)
    other = "SessionEnd" if kind == "Frame" else "Frame"
    many = {**base, **{f"k{i}": i for i in range(40)}}
    int_key: dict[object, object] = {key: value for key, value in base.items()}
    int_key[1] = 2
    deep = b"\x91" * 1000 + b"\xc0"
    return [
        ("empty payload", b"", "MALFORMED", None),
        ("truncated", good[: len(good) // 2], "MALFORMED", None),
        ("trailing byte", good + b"\x00", "MALFORMED", None),
        ("reserved byte 0xc1", b"\xc1", "MALFORMED", None),
        ("top level is an array", pack(list(base.values())), "MALFORMED", None),
        ("top level is an int", pack(7), "MALFORMED", None),
        ("integer map key", pack(int_key), "MALFORMED", None),
        ("invalid utf-8", pack_map({**base, "type": Raw(b"\xa2\xff\xfe")}), "MALFORMED", None),
        (
            "nested 2000 deep",
            pack_map({**base, "x": Raw(b"\x91" * 2000 + b"\xc0")}),
            "MALFORMED",
            None,
        ),
        ("missing type", pack(edit(base, type=DROP)), "UNKNOWN_TYPE", None),
        ("unknown type", pack(edit(base, type="Bogus")), "UNKNOWN_TYPE", None),
        ("type as bin", pack(edit(base, type=kind.encode())), "INVALID", None),
        (f"a {other} where a {kind} is expected", pack(BASE[other]), "UNKNOWN_TYPE", None),
        ("type nested 1000 deep", pack_map({**base, "type": Raw(deep)}), "UNKNOWN_TYPE", None),
        ("v nested 1000 deep", pack_map({**base, "v": Raw(deep)}), "UNSUPPORTED_VERSION", None),
        ("missing v", pack(edit(base, v=DROP)), "UNSUPPORTED_VERSION", None),
        ("v is 1 (superseded)", pack(edit(base, v=1)), "UNSUPPORTED_VERSION", None),
        ("v is 2 (superseded)", pack(edit(base, v=2)), "UNSUPPORTED_VERSION", None),
        ("v is 3 (superseded)", pack(edit(base, v=3)), "UNSUPPORTED_VERSION", None),
        ("v is 5", pack(edit(base, v=5)), "UNSUPPORTED_VERSION", None),
        ("v is true", pack(edit(base, v=True)), "UNSUPPORTED_VERSION", None),
        ("v is a string", pack(edit(base, v="4")), "UNSUPPORTED_VERSION", None),
        ("unknown field", pack(edit(base, color="red")), "INVALID", None),
        ("bin value", pack(edit(base, blob=b"\x00\x01")), "INVALID", None),
        ("extension value", pack(edit(base, ext=msgpack.ExtType(5, b"x"))), "INVALID", None),
        ("map of 40 extra entries", pack(many), "INVALID", None),
        ("key v twice, same value", pack_pairs([*base.items(), ("v", 4)]), "INVALID", None),
        ("key type twice", pack_pairs([*base.items(), ("type", other)]), "INVALID", None),
        (
            "string of 1025 bytes",
            pack(edit(base, x="x" * 1025)),
            "LIMIT_EXCEEDED",
            "max_detail_len",
        ),
        *[
            (f"missing {field}", pack(edit(base, **{field: DROP})), "INVALID", None)
            for field in list(base)[2:4]
        ],
    ]


def names(kind: str, field: str) -> tuple[list[Valid], list[Invalid]]:
    """Return the name-rule cases of one name field."""
    base = BASE[kind]
    bad = [("'*'", "run*1"), ("'/'", "a/b"), ("'$'", "a$b"), ("'@'", "@a"), ("a space", "a b")]
    bad += [("non-ASCII", "r\u00e9sum\u00e9"), ("a leading '.'", ".a"), ("a leading '-'", "-a")]
    bad += [("a trailing newline", "a\n"), ("nothing (empty)", "")]
    return [(f"{field} of 64 chars", pack(edit(base, **{field: "S_0-." * 12 + "abcd"})), True)], [
        *[
            (f"{field} with {what}", pack(edit(base, **{field: value})), "BAD_NAME", None)
            for what, value in bad
        ],
        (f"{field} of 65 chars", pack(edit(base, **{field: "s" * 65})), "BAD_NAME", "max_name_len"),
        (f"{field} is an int", pack(edit(base, **{field: 5})), "INVALID", None),
        (f"{field} as bin", pack(edit(base, **{field: b"run"})), "INVALID", None),
    ]


def specific(kind: str) -> tuple[list[Valid], list[Invalid]]:
    """Return the cases that belong to one message type."""
    b = BASE[kind]
    valid: list[Valid] = [("typical", pack(b), True)]
    invalid: list[Invalid] = []

    def ok(name: str, canonical: bool = True, **changes: object) -> None:
        valid.append((name, pack(edit(b, **changes)), canonical))

    def bad(name: str, error: str, limit: str | None = None, /, **changes: object) -> None:
        invalid.append((name, pack(edit(b, **changes)), error, limit))

    if kind == "Frame":
        ok("empty features, pose null", features=[], pose=None)
        ok("pose omitted (reader fills null)", canonical=False, pose=DROP)
        ok("seq 0, negative stamp", seq=0, stamp_s=-12.5)
        ok("largest seq and feature ids", seq=2**53 - 1, features=[0, 2**32, 2**53 + 1, 2**63 - 1])
        ok("integral stamp sent as int", canonical=False, stamp_s=1718000000)
        f32 = edit(b, stamp_s=0.5)
        valid.append(("float32 stamp and pose", pack(f32, use_single_float=True), False))
        valid.append(("seq as uint64", pack_map(edit(b, seq=wide(42))), False))
        bad("seq as string", "INVALID", seq="42")
        bad("seq true", "INVALID", seq=True)
        bad("seq as float", "INVALID", seq=42.0)
        bad("seq negative", "INVALID", seq=-1)
        bad("seq 2**53", "LIMIT_EXCEEDED", "max_seq", seq=2**53)
        bad("seq 2**64-1", "LIMIT_EXCEEDED", "max_seq", seq=2**64 - 1)
        bad("feature id negative", "INVALID", features=[1, -1])
        bad("feature id 2**63", "LIMIT_EXCEEDED", "max_feature_id", features=[2**63])
        bad("feature id true", "INVALID", features=[True])
        bad("feature id as float", "INVALID", features=[1.0])
        bad("feature id as string", "INVALID", features=["17"])
        bad("features a map", "INVALID", features={"a": 1})
        bad("features null", "INVALID", features=None)
        bad("4097 features", "LIMIT_EXCEEDED", "max_features_per_frame", features=[0] * 4097)
        bad("stamp NaN", "INVALID", stamp_s=float("nan"))
        bad("stamp infinite", "INVALID", stamp_s=float("inf"))
        bad("stamp as string", "INVALID", stamp_s="1718000000.25")
        bad("stamp true", "INVALID", stamp_s=True)
        bad("stamp null", "INVALID", stamp_s=None)
        bad("pose of 2 values", "INVALID", pose=[1.0, 2.0])
        bad("pose with NaN", "INVALID", pose=[1.0, float("nan"), 0.0])
        bad("pose of strings", "INVALID", pose=["1", "2", "3"])
        bad("pose a map", "INVALID", pose={"x_m": 1.0})
    elif kind == "SessionEnd":
        ok("no frames sent", last_seq=None)
        bad("last_seq negative", "INVALID", last_seq=-1)
        bad("last_seq as string", "INVALID", last_seq="42")
        bad("last_seq 2**53", "LIMIT_EXCEEDED", "max_seq", last_seq=2**53)
        bad("stamp NaN", "INVALID", stamp_s=float("nan"))
    elif kind == "Transition":
        ok("disconnected", reason="DISCONNECTED", ncut=None, lambda2=None)
        ok("coalesced batch", batch_frames=3, boundary_seq=42, boundary_features=[])
        bad("boundary after seq", "INVALID", boundary_seq=43)
        bad("spectral without ncut", "INVALID", ncut=None)
        bad("disconnected with ncut", "INVALID", reason="DISCONNECTED", lambda2=None)
        bad("reason lower case", "INVALID", reason="spectral")
        bad("batch_frames 0", "INVALID", batch_frames=0)
        bad("closed first_seq after last_seq", "INVALID", closed={**SUMMARY_A, "first_seq": 50})
        bad("closed with unknown field", "INVALID", closed={**SUMMARY_A, "area_m2": 12.0})
        bad("closed missing features", "INVALID", closed=edit(SUMMARY_A, features=DROP))
        bad(
            "opened last_seq 2**53",
            "LIMIT_EXCEEDED",
            "max_seq",
            opened={**SUMMARY_B, "last_seq": 2**53},
        )
        bad("boundary feature 2**63", "LIMIT_EXCEEDED", "max_feature_id", boundary_features=[2**63])
        bad("ncut NaN", "INVALID", ncut=float("nan"))
        bad("fleet with '*'", "BAD_NAME", fleet="*")
        bad("robot with '#'", "BAD_NAME", robot="amr#7")
        bad("instance with '?'", "BAD_NAME", instance="a?")
        ok("largest epoch, last partition", epoch=2**53 - 1, partition=PARTITIONS - 1)
        bad("epoch 0", "INVALID", epoch=0)
        bad("epoch null", "INVALID", epoch=None)
        bad("epoch 2**53", "INVALID", epoch=2**53)
        bad(f"partition {PARTITIONS}", "INVALID", partition=PARTITIONS)
        bad("partition missing", "INVALID", partition=DROP)
        ok(
            "recognised revisit",
            reason="RECOGNISED",
            ncut=None,
            lambda2=None,
            closed={**SUMMARY_A, "id": 2},
            opened={**SUMMARY_B, "id": 3},
            area=0,
            left_area=1,
            revisit=True,
        )
        bad("recognised with ncut", "INVALID", reason="RECOGNISED", lambda2=None)
        bad("area equals left_area", "INVALID", area=0)
        bad("area negative", "INVALID", area=-1)
        bad("revisit as int", "INVALID", revisit=1)
        bad("revisit missing", "INVALID", revisit=DROP)
        ok(
            "after lost state: a new incarnation",
            incarnation=1200,
            seq=1242,
            boundary_seq=1238,
            closed={**SUMMARY_A, "first_seq": 1200, "last_seq": 1241},
            opened={**SUMMARY_B, "first_seq": 1238, "last_seq": 1242},
        )
        bad("incarnation after closed first_seq", "INVALID", incarnation=1)
        bad("incarnation missing", "INVALID", incarnation=DROP)
        bad("incarnation negative", "INVALID", incarnation=-1)
        bad("incarnation 2**53", "LIMIT_EXCEEDED", "max_seq", incarnation=2**53)
    elif kind == "Error":
        ok(
            "nothing known about the sender",
            fleet=None,
            robot=None,
            session=None,
            seq=None,
            code="MALFORMED",
            detail="not a msgpack value",
        )
        ok("detail of 1024 chars", detail="d" * 1024)
        for code in ("DURABILITY_LOST", "DURABILITY_BACK"):
            ok(
                f"{code.lower().replace('_', ' ')}, from the service itself",
                fleet=None,
                robot=None,
                session=None,
                seq=None,
                epoch=None,
                code=code,
                detail="state store: disk full",
            )
        bad("unknown code", "INVALID", code="NOPE")
        bad("code lower case", "INVALID", code="seq_gap")
        bad("code as int", "INVALID", code=3)
        bad("detail of 1025 chars", "LIMIT_EXCEEDED", "max_detail_len", detail="d" * 1025)
        bad("fleet empty", "BAD_NAME", fleet="")
        bad("epoch as float", "INVALID", epoch=1.0)
    elif kind == "SessionState":
        ok("after lost state", incarnation=30)
        bad("incarnation missing", "INVALID", incarnation=DROP)
        ok(
            "closed, no frames yet",
            open=False,
            last_seq=None,
            frames_applied=0,
            frames_duplicate=0,
            frames_rejected=0,
            transitions=0,
            current_area=0,
            current_submap={
                "id": 0,
                "first_seq": 0,
                "last_seq": 0,
                "frame_count": 0,
                "features": [],
            },
            closed_submaps=[],
            nodes=0,
            edges=0,
        )
        bad("open as int", "INVALID", open=1)
        bad("negative counter", "INVALID", frames_applied=-1)
        bad("closed_submaps of ints", "INVALID", closed_submaps=[1])
        bad("current_submap null", "INVALID", current_submap=None)
        bad("epoch missing", "INVALID", epoch=DROP)
        ok("method areas", method="areas", current_area=0)
        bad("unknown method", "INVALID", method="fancy")
        bad("current_area missing", "INVALID", current_area=DROP)
    elif kind == "Submap":
        ok("open submap", open=True, summary=SUMMARY_B)
        bad("summary missing features", "INVALID", summary=edit(SUMMARY_A, features=DROP))
        bad("summary negative id", "INVALID", summary={**SUMMARY_A, "id": -1})
        bad("open null", "INVALID", open=None)
    elif kind == "AreaGraph":
        ok("paper method, one area", method="paper", areas=[{**AREA_A, "visits": 1}], passages=[])
        ok("passage without boundary features", passages=[{**PASSAGE, "boundary_features": []}])
        ok(
            "largest boundary feature id",
            passages=[{**PASSAGE, "boundary_features": [[2**63 - 1, 1]]}],
        )
        ok("no frames yet", areas=[], passages=[])
        bad("areas out of order", "INVALID", areas=[AREA_B, AREA_A])
        bad("area listed twice", "INVALID", areas=[AREA_A, AREA_A], passages=[])
        bad("passage to an unlisted area", "INVALID", passages=[{**PASSAGE, "b": 5}])
        bad("passage with a >= b", "INVALID", passages=[{**PASSAGE, "a": 2, "b": 0}])
        bad("passage counting nothing", "INVALID", passages=[{**PASSAGE, "a_to_b": 0, "b_to_a": 0}])
        bad("passages listed twice", "INVALID", passages=[PASSAGE, PASSAGE])
        bad("area with 0 visits", "INVALID", areas=[{**AREA_A, "visits": 0}, AREA_B])
        bad("area first_seq after last_seq", "INVALID", areas=[{**AREA_A, "first_seq": 91}, AREA_B])
        bad(
            "boundary pair of 3",
            "INVALID",
            passages=[{**PASSAGE, "boundary_features": [[3, 2, 1]]}],
        )
        bad("boundary feature bare", "INVALID", passages=[{**PASSAGE, "boundary_features": [3]}])
        bad(
            "boundary feature 2**63",
            "LIMIT_EXCEEDED",
            "max_feature_id",
            passages=[{**PASSAGE, "boundary_features": [[2**63, 1]]}],
        )
        bad(
            "boundary count 2**53",
            "INVALID",
            passages=[{**PASSAGE, "boundary_features": [[3, 2**53]]}],
        )
        bad(
            "area feature 2**63",
            "LIMIT_EXCEEDED",
            "max_feature_id",
            areas=[{**AREA_A, "features": [2**63]}, AREA_B],
        )
        bad("unknown method", "INVALID", method="paper2")
        bad(
            "area last_seq 2**53",
            "LIMIT_EXCEEDED",
            "max_seq",
            areas=[{**AREA_A, "last_seq": 2**53}, AREA_B],
        )
        bad("epoch 0", "INVALID", epoch=0)
    elif kind == "Health":
        ok("uptime sent as int", canonical=False, uptime_s=0)
        bad("uptime negative", "INVALID", uptime_s=-1.0)
        bad("uptime NaN", "INVALID", uptime_s=float("nan"))
        bad("version empty", "INVALID", version="")
        bad("sessions as string", "INVALID", sessions="12")
        ok("no partitions yet", partitions=[], standby=[], queue_depth=0, lag_s=0.0)
        bad(f"partition {PARTITIONS}", "INVALID", partitions=[PARTITIONS])
        bad("lag negative", "INVALID", lag_s=-0.5)
    return valid, invalid


def vectors(kind: str) -> dict[str, object]:
    """Build, decode and check every vector of one message type."""
    valid, invalid = specific(kind)
    invalid += common(kind)
    if "session" in BASE[kind]:
        more_valid, more_invalid = names(kind, "session")
        valid += more_valid
        invalid += more_invalid
    model = MESSAGE_TYPES[kind]
    out_valid = []
    for name, payload, canonical in valid:
        message = decode(payload, model)
        if (encode(message) == payload) != canonical:
            msg = f"{kind} {name!r}: declared canonical={canonical}, the codec disagrees"
            raise SystemExit(msg)
        json_value = message.model_dump(mode="json")
        out_valid.append(
            {"name": name, "hex": payload.hex(), "json": json_value, "canonical": canonical}
        )
    out_invalid = []
    for name, payload, code, limit in invalid:
        try:
            decode(payload, model)
        except WireError as exc:
            if (exc.code, exc.limit) != (code, limit):
                msg = f"{kind} {name!r}: declared {code}/{limit}, got {exc.code}/{exc.limit}: {exc}"
                raise SystemExit(msg) from exc
        else:
            msg = f"{kind} {name!r}: declared {code}, but it decodes"
            raise SystemExit(msg)
        out_invalid.append({"name": name, "hex": payload.hex(), "code": code, "limit": limit})
    names_seen = [case["name"] for case in out_valid + out_invalid]
    if len(set(names_seen)) != len(names_seen):
        msg = f"{kind}: vector names are not unique"
        raise SystemExit(msg)
    return {"type": kind, "valid": out_valid, "invalid": out_invalid}


def render(kind: str) -> str:
    """Return the file text of one vector file."""
    if kind == "partition":
        data = partition_vectors()
    elif kind == "fleet_areas":
        data = fleet_area_vectors()
    else:
        data = vectors(kind)
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write the vector files, or with --check exit 1 if any is stale."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if stale")
    parser.add_argument("--out", type=Path, default=HERE, help="output folder")
    args = parser.parse_args(argv)
    stale = []
    for kind in [*MESSAGE_TYPES, "partition", "fleet_areas"]:
        path: Path = args.out / f"{kind}.json"
        text = render(kind)
        if args.check:
            if not path.is_file() or path.read_text(encoding="utf-8") != text:
                stale.append(path.name)
        else:
            path.write_text(text, encoding="utf-8")
    if stale:
        sys.stderr.write(f"stale vectors: {', '.join(stale)}; run schemas/vectors/generate.py\n")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

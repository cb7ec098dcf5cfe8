"""Every command, given bad arguments, answers in one line on stderr: never a traceback.

Exit code 2 when the command line itself is wrong (an unknown option, a value of the wrong
kind or out of range: argparse finds it), 1 when the command ran and failed (a missing or
malformed file, no router, a port taken). The line starts with ``lessmap COMMAND:`` and
carries neither a Python traceback nor Zenoh's Rust source paths (``.rs:``).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from typing import TYPE_CHECKING, NamedTuple

import pytest

from tests.conftest import free_port

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

pytestmark = pytest.mark.timeout(120)

#: Every command must appear in the table below (checked by a test).
SHORT_S = "1"  # --connect-timeout of the cases that wait for a router nobody runs


class Case(NamedTuple):
    """One command line, the exit code it must give and a fragment of its one line."""

    argv: tuple[str, ...]
    code: int
    says: str


# Placeholders, filled per run: {missing} a path that does not exist, {empty} an empty
# file, {binary} a file that is not UTF-8, {frames} a valid frames file, {taken} a TCP
# endpoint something listens on, {nobody} one nothing listens on, {file} a regular file.
CASES: dict[str, list[Case]] = {
    "segment": [
        Case(("segment", "{missing}"), 1, "{missing}: no such file"),
        Case(("segment", "{empty}"), 1, "no frames"),
        Case(("segment", "{binary}"), 1, "not UTF-8"),
        Case(("segment", "{frames}", "--robot", "nobody"), 1, "no frames of robot nobody"),
        Case(("segment", "{frames}", "--ncut-min", "x"), 2, "--ncut-min"),
    ],
    "rooms": [
        Case(("rooms", "{missing}", "--map", "{missing}", "-o", "{dir}/r"), 1, "no such file"),
        Case(("rooms", "{frames}", "--map", "{missing}", "-o", "{dir}/r"), 1, "no such file"),
        Case(("rooms", "{frames}", "-o", "{dir}/r"), 2, "required: --map"),
    ],
    "eval": [
        Case(("eval", "{missing}"), 1, "{missing}: no such file"),
        Case(("eval", "{empty}"), 1, "holds no frames"),
        Case(("eval", "{binary}"), 1, "not UTF-8"),
        Case(("eval", "{frames}", "--jobs", "0"), 2, "--jobs: must be at least 1"),
    ],
    "plot": [
        Case(("plot", "{missing}", "-o", "{dir}"), 1, "{missing}: no such file"),
        Case(("plot", "--area-graph", "{binary}", "-o", "{dir}/g.png"), 1, "not UTF-8"),
        Case(("plot", "--area-graph", "{empty}", "-o", "{dir}/g.png"), 1, "not JSON"),
    ],
    "sim": [
        Case(("sim", "--rooms", "0", "-o", "{dir}"), 2, "--rooms: must be at least 1"),
        Case(("sim", "--robots", "-1", "-o", "{dir}"), 2, "--robots: must be at least 1"),
        Case(("sim", "--fov", "0", "-o", "{dir}"), 2, "--fov: must be above 0"),
        Case(("sim", "--fov", "361", "-o", "{dir}"), 2, "at most 360"),
        Case(("sim", "--speed", "0", "--publish"), 2, "--speed: must be a positive number"),
        Case(("sim", "--frames", "ten", "-o", "{dir}"), 2, "expected a whole number"),
        Case(("sim", "--frames", "5", "-o", "{file}/run"), 1, "{file}/run"),
        Case(
            ("sim", "--frames", "5", "--publish", "-e", "{nobody}", "--connect-timeout", SHORT_S),
            1,
            "no Zenoh router answered at {nobody}",
        ),
    ],
    "replay": [
        Case(("replay", "{missing}"), 1, "{missing}: no such file"),
        Case(("replay", "{empty}"), 1, "no frames to publish"),
        Case(("replay", "{binary}"), 1, "not UTF-8"),
        Case(("replay", "{frames}", "-c", "{missing}"), 1, "-c/--zenoh-config {missing}"),
        Case(
            ("replay", "{frames}", "-e", "{nobody}", "--connect-timeout", SHORT_S),
            1,
            "is `lessmap serve` or `lessmap router` running there?",
        ),
    ],
    "status": [
        Case(("status", "-e", "{nobody}", "--connect-timeout", SHORT_S), 1, "{nobody}"),
        Case(("status", "-e", "garbage"), 1, "invalid endpoint garbage"),
        Case(("status", "-e", "tcp/127.0.0.1:99999", "--connect-timeout", SHORT_S), 1, "99999"),
        Case(("status", "-c", "{missing}"), 1, "-c/--zenoh-config {missing}: no such file"),
        Case(("status", "-c", "{binary}"), 1, "Zenoh config {binary}"),
        Case(("status", "--connect-timeout", "0"), 2, "--connect-timeout"),
        Case(("status", "--connect-timeout", "inf"), 2, "--connect-timeout"),
        Case(("status", "-m", "router"), 2, "invalid choice"),
        Case(
            ("status", "-m", "peer", "-l", "{taken}", "--connect-timeout", SHORT_S),
            1,
            "cannot listen on {taken}: the port is already in use",
        ),
    ],
    "watch": [
        Case(("watch", "-e", "{nobody}", "--duration", "1"), 1, "{nobody}"),
        Case(("watch", "-c", "{missing}"), 1, "no such file"),
        Case(("watch", "--interval", "-1"), 2, "--interval"),
    ],
    "areas": [
        Case(
            ("areas", "--fleet", "f", "-e", "{nobody}", "--connect-timeout", SHORT_S), 1, "{nobody}"
        ),
        Case(("areas", "--fleet", "f", "-c", "{missing}"), 1, "no such file"),
        Case(("areas", "--fleet", "f", "--timeout", "0"), 2, "--timeout"),
    ],
    "serve": [
        Case(("serve", "-c", "{missing}"), 1, "no such file"),
        Case(("serve", "--config", "{missing}"), 1, "{missing}"),
        Case(("serve", "--config", "{binary}"), 1, "{binary}"),
        Case(("serve", "--memory-only", "-l", "{taken}"), 1, "-l/--listen"),
        Case(
            ("serve", "--memory-only", "-m", "client", "-e", "{nobody}", "--connect-timeout", "1"),
            1,
            "no Zenoh router answered at {nobody}",
        ),
        Case(("serve", "--workers", "0"), 2, "from flag --workers"),
        Case(("serve", "--instance", "a/b", "-l", "{taken}"), 1, "-l/--listen"),
        Case(("serve", "-m", "nonsense"), 2, "invalid choice"),
    ],
    "router": [
        Case(("router", "-l", "{taken}"), 1, "cannot listen on {taken}"),
        Case(("router", "-c", "{missing}"), 1, "no such file"),
        Case(("router", "-c", "{empty}"), 1, "lessmap router: "),
        Case(("router", "-l", "garbage"), 1, "garbage"),
    ],
    "demo": [
        Case(("demo", "-l", "{taken}", "--duration", "1"), 1, "-l/--listen"),
        Case(("demo", "--robots", "0"), 2, "--robots"),
        Case(("demo", "--duration", "-5"), 2, "--duration"),
        Case(("demo", "--duration", "0"), 2, "--duration"),
    ],
    "certs": [
        Case(("certs",), 2, "-o/--out"),
        Case(("certs", "--fleet", "f", "-o", "{file}/site"), 1, "{file}/site"),
    ],
    "ros": [
        Case(
            ("ros", "-e", "{nobody}", "--connect-timeout", SHORT_S, "--duration", "1"),
            1,
            "rmw_zenohd",
        ),
        Case(("ros", "-c", "{missing}"), 1, "no such file"),
        Case(("ros", "--max-features-per-frame", "0"), 2, "must be at least 1"),
        Case(("ros", "--publish-ros=no"), 2, "--publish-ros"),
    ],
    "import": [
        Case(("import", "{missing}"), 1, "{missing}: no such file"),
        Case(("import", "{frames}", "-o", "{missing}/x.frames.jsonl"), 1, "no folder"),
    ],
    "view": [
        Case(
            ("view", "--fleet", "f", "-e", "{nobody}", "--connect-timeout", SHORT_S), 1, "{nobody}"
        ),
        Case(("view", "--fleet", "f", "-c", "{missing}"), 1, "no such file"),
        Case(("view", "--fleet", "f", "--port", "-1"), 2, "--port"),
    ],
    "record": [
        Case(
            (
                "record",
                "--fleet",
                "f",
                "--mcap",
                "{dir}/r.mcap",
                "-e",
                "{nobody}",
                "--connect-timeout",
                SHORT_S,
            ),
            1,
            "{nobody}",
        ),
        Case(("record", "--fleet", "f", "--mcap", "{frames}"), 1, "--overwrite"),
    ],
}


@pytest.fixture(scope="module")
def places(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """The files and endpoints the placeholders stand for; {taken} is held for the module."""
    root = tmp_path_factory.mktemp("bad")
    (root / "empty.frames.jsonl").write_bytes(b"")
    (root / "binary.frames.jsonl").write_bytes(b"\xff\xfe\x00 not text\n")
    (root / "ok.frames.jsonl").write_text(
        "".join(
            f'{{"robot": "r", "seq": {i}, "stamp": {i}.0, "features": [{i}, {i + 1}, {i + 2}]}}\n'
            for i in range(20)
        ),
        encoding="utf-8",
    )
    (root / "plain.txt").write_text("a file, not a folder\n", encoding="utf-8")
    (root / "out").mkdir()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        yield {
            "missing": str(root / "missing.frames.jsonl"),
            "empty": str(root / "empty.frames.jsonl"),
            "binary": str(root / "binary.frames.jsonl"),
            "frames": str(root / "ok.frames.jsonl"),
            "file": str(root / "plain.txt"),
            "dir": str(root / "out"),
            "taken": f"tcp/127.0.0.1:{taken.getsockname()[1]}",
            "nobody": f"tcp/127.0.0.1:{free_port()}",
        }


def run_lessmap(argv: list[str], state: Path) -> subprocess.CompletedProcess[str]:
    """Run ``python -m lessmap`` with a clean environment (no LESSMAP_* settings)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("LESSMAP_", "RUST_LOG"))}
    env["XDG_STATE_HOME"] = str(state)
    return subprocess.run(
        [sys.executable, "-m", "lessmap", *argv],
        capture_output=True,
        text=True,
        timeout=90,
        check=False,
        env=env,
        stdin=subprocess.DEVNULL,
    )


TABLE = [
    pytest.param(case, id=f"{name}:{' '.join(case.argv[1:])}")
    for name, cases in CASES.items()
    for case in cases
]


@pytest.mark.parametrize("case", TABLE)
def test_a_bad_argument_is_one_line_and_the_right_exit_code(
    case: Case, places: dict[str, str], tmp_path: Path
) -> None:
    argv = [arg.format(**places) for arg in case.argv]
    result = run_lessmap(argv, tmp_path)
    lines = result.stderr.splitlines()
    assert result.returncode == case.code, result.stderr
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    assert ".rs:" not in result.stderr
    assert lines[0].startswith(f"lessmap {argv[0]}: "), lines
    assert case.says.format(**places) in lines[0]


def test_the_table_covers_every_command() -> None:
    from lessmap.cli.app import COMMANDS

    assert set(COMMANDS) <= set(CASES), set(COMMANDS) - set(CASES)


def test_bare_lessmap_prints_a_short_usage(tmp_path: Path) -> None:
    result = run_lessmap([], tmp_path)
    assert result.returncode == 2
    lines = result.stderr.splitlines()
    assert lines[0].startswith("usage: lessmap ")
    assert "serve" in lines[1]
    assert len(lines) <= 4
    assert "required" not in result.stderr


def test_global_options_after_the_command(places: dict[str, str], tmp_path: Path) -> None:
    result = run_lessmap(["segment", places["frames"], "--log-format", "json", "-v"], tmp_path)
    assert result.returncode == 0, result.stderr
    result = run_lessmap(["-v", "segment", places["frames"], "-vv"], tmp_path)
    assert result.returncode == 0, result.stderr

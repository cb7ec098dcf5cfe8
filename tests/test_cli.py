"""The ``lessmap`` entry point: lazy subcommands, help, version, no private argparse API."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

from lessmap.cli.app import COMMANDS, build_parser, command_parser, main

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "scipy", "zenoh", "pydantic", "lessmap_schemas", "lessmap.core")


def loaded_after(argv: list[str]) -> set[str]:
    """Run the command line in a fresh interpreter; return the heavy modules it imported."""
    code = (
        "import sys\n"
        "from lessmap.cli.app import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print('LOADED', *(m for m in sys.modules if m.startswith({HEAVY!r})))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    [line] = [line for line in result.stdout.splitlines() if line.startswith("LOADED")]
    return set(line.split()[1:])


@pytest.mark.parametrize("argv", [["--version"], ["--help"]], ids=["version", "help"])
def test_version_and_help_import_nothing_heavy(argv: list[str]) -> None:
    assert loaded_after(argv) == set()


def test_a_command_imports_only_its_own_module() -> None:
    loaded = loaded_after(["sim", "--help"])
    assert "lessmap_schemas" in loaded  # sim publishes through the SDK
    assert "scipy" not in loaded  # but evaluation, serve and segment were not loaded


def test_version_as_a_script() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "lessmap", "--version"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0
    assert result.stdout.startswith("lessmap ")
    assert result.stdout.split()[1][0].isdigit()


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stopped:
        main(["--help"])
    assert stopped.value.code == 0
    out = capsys.readouterr().out
    for name, command in COMMANDS.items():
        assert f"  {name} " in out
        assert command.help in out


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_has_help(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stopped:
        main([name, "--help"])
    assert stopped.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: lessmap {name} ")
    parser, run = command_parser(name)
    assert callable(run)
    assert parser.description  # every command describes itself


def test_global_options_come_before_the_command(capsys: pytest.CaptureFixture[str]) -> None:
    top = build_parser().parse_args(["-vv", "--log-format", "json", "segment", "F", "--robot", "a"])
    assert (top.verbose, top.log_format, top.command) == (2, "json", "segment")
    assert top.arguments == ["F", "--robot", "a"]
    with pytest.raises(SystemExit) as stopped:
        main(["no-such-command"])
    assert stopped.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_no_private_argparse_api() -> None:
    for path in [*(ROOT / "service").rglob("*.py"), *(ROOT / "clients").rglob("*.py")]:
        text = path.read_text(encoding="utf-8")
        assert "_SubParsersAction" not in text, path
        assert "argparse._" not in text, path


def test_a_missing_optional_extra_is_one_line(tmp_path: Path) -> None:
    # A fresh `pip install lessmap` has no matplotlib: plotting must say which extra to add.
    frames = tmp_path / "walk.frames.jsonl"
    frames.write_text(
        "\n".join(
            json.dumps({"robot": "r", "seq": i, "stamp": float(i), "features": [i, i + 1]})
            for i in range(5)
        )
        + "\n",
        encoding="utf-8",
    )
    code = (
        "import sys; sys.modules['matplotlib'] = None; from lessmap.cli.app import main; "
        f"sys.exit(main(['plot', {str(frames)!r}, '--out', {str(tmp_path / 'out')!r}]))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 1, result.stderr
    assert result.stderr.strip().splitlines() == [
        "lessmap plot: this needs matplotlib, from lessmap's optional extra eval: "
        "pip install '.[eval]' in the repository (README, Install)"
    ]


@pytest.mark.parametrize("name", COMMANDS)
def test_every_help_shows_the_defaults(name: str) -> None:
    parser, _ = command_parser(name)
    text = " ".join(parser.format_help().split())
    for action in parser._actions:
        default = action.default
        empty = isinstance(default, list | tuple) and not default
        unset = default is None or default is False or default is argparse.SUPPRESS or empty
        if unset or not action.option_strings or action.help == argparse.SUPPRESS:
            continue
        help_text = " ".join((action.help or "").split())
        assert "default" in help_text or f"(default: {action.default})" in text, (
            action.option_strings
        )


NETWORKED = ("serve", "status", "replay", "watch", "areas", "sim", "ros", "view", "record")


@pytest.mark.parametrize("name", NETWORKED)
def test_networked_commands_share_one_zenoh_grammar(name: str) -> None:
    from lessmap_client.cli_options import (
        CONNECT_HELP,
        DEFAULT_CONNECT_TIMEOUT_S,
        LISTEN_HELP,
        TIMEOUT_HELP,
        ZENOH_CONFIG_HELP,
    )

    parser, _ = command_parser(name)
    options = {o: a for a in parser._actions for o in a.option_strings}
    for short, long, help_text in (
        ("-e", "--connect", CONNECT_HELP),
        ("-l", "--listen", LISTEN_HELP),
        ("-c", "--zenoh-config", ZENOH_CONFIG_HELP),
    ):
        assert options[short] is options[long], (name, short)
        assert (options[long].help or "").startswith(help_text)
    assert options["-m"] is options["--mode"]
    assert "client = through a router" in (options["-m"].help or "")
    timeout = options["--connect-timeout"]
    assert (timeout.help or "").startswith(TIMEOUT_HELP)
    if name != "serve":  # serve's default is its settings' (the same value)
        assert timeout.default == DEFAULT_CONNECT_TIMEOUT_S
    args = parser.parse_args(
        [
            *(["FILE"] if name == "replay" else []),
            *(["--fleet", "f"] if name in ("areas", "view") else []),
        ]
        + (["--mcap", "x.mcap", "--fleet", "f"] if name == "record" else [])
        + ["-v", "--log-format", "json"]
    )
    assert (args.verbose, args.log_format) == (1, "json")  # global options after the command

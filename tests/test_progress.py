"""Progress on stderr: drawn on a terminal, absent from pipes, never touching stdout.

The commands run as a user runs them, in a subprocess; the terminal is a pseudo-terminal
(Python's ``pty``) on stderr only, so stdout stays a pipe and can be compared byte for byte
with a run where both are pipes.
"""

from __future__ import annotations

import os
import pty
import re
import subprocess
import sys
import threading
from typing import TYPE_CHECKING

import pytest

from tests.conftest import dataset

if TYPE_CHECKING:
    from collections.abc import Sequence

#: A small sweep, so the eval takes seconds: three runs of LESS-mapping on dlr.
SWEEP = ("--sweep-ncut", "0.1", "0.2", "--sweep-lambda2", "0.1")
ENV = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "120"}


def untimed(out: bytes) -> bytes:
    """``out`` with the summary's timings blanked: the only bytes that differ between runs."""
    return re.sub(rb'"(elapsed_s|ms_per_frame)": [0-9.e-]+', rb'"\1": _', out)


def run_piped(argv: Sequence[str]) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(
        [sys.executable, "-m", "lessmap", *argv], capture_output=True, env=ENV, timeout=300
    )


def run_with_terminal_stderr(argv: Sequence[str]) -> tuple[int, bytes, bytes]:
    """Run with stderr on a pseudo-terminal and stdout on a pipe: code, stdout, stderr."""
    controller, terminal = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "lessmap", *argv],
        stdout=subprocess.PIPE,
        stderr=terminal,
        env=ENV,
    )
    os.close(terminal)
    drawn = bytearray()

    def drain() -> None:
        while True:
            try:
                chunk = os.read(controller, 65536)
            except OSError:  # EIO: the last holder of the terminal closed it
                return
            if not chunk:
                return
            drawn.extend(chunk)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    out, _ = proc.communicate(timeout=300)
    reader.join(10)
    os.close(controller)
    return proc.returncode, out, bytes(drawn)


@pytest.mark.slow
def test_eval_draws_progress_on_a_terminal_and_its_output_is_unchanged() -> None:
    frames = str(dataset("dlr.frames.jsonl"))
    piped = run_piped(["eval", frames, *SWEEP])
    assert piped.returncode == 0, piped.stderr
    assert b"LESS-mapping" not in piped.stderr  # no bar into a pipe
    code, out, drawn = run_with_terminal_stderr(["eval", frames, *SWEEP])
    assert code == 0, drawn.decode(errors="replace")
    text = drawn.decode(errors="replace")
    assert "lessmap eval: LESS-mapping" in text
    assert "lessmap eval: threshold sweep, 2 pairs" in text
    assert "2/2" in text  # the sweep's bar counted its runs
    assert out == piped.stdout
    quiet_code, quiet_out, quiet_drawn = run_with_terminal_stderr(["-q", "eval", frames, *SWEEP])
    assert quiet_code == 0
    assert b"LESS-mapping" not in quiet_drawn
    assert quiet_out == piped.stdout


def test_segment_draws_progress_on_a_terminal_and_its_output_is_unchanged() -> None:
    frames = str(dataset("dlr.frames.jsonl"))
    piped = run_piped(["segment", frames])
    assert piped.returncode == 0, piped.stderr
    assert piped.stdout.count(b"\n") > 10  # transitions, then the summary
    code, out, drawn = run_with_terminal_stderr(["segment", frames])
    assert code == 0, drawn.decode(errors="replace")
    assert "lessmap segment: segmenting dlr.frames.jsonl" in drawn.decode(errors="replace")
    assert untimed(out) == untimed(piped.stdout)
    # -q after the command name, as every global option may be.
    code, out, drawn = run_with_terminal_stderr(["segment", frames, "-q"])
    assert code == 0
    assert b"segmenting" not in drawn
    assert untimed(out) == untimed(piped.stdout)


def test_replay_prints_progress_lines_on_a_terminal_or_when_asked() -> None:
    import argparse

    from lessmap_client.cli_client import PROGRESS_S, _progress_interval_s

    asked = argparse.Namespace(progress=0.5, quiet=False)
    assert _progress_interval_s(asked) == 0.5
    assert _progress_interval_s(argparse.Namespace(progress=0.5, quiet=True)) == 0.0
    default = argparse.Namespace(progress=None, quiet=False)
    assert _progress_interval_s(default) == (PROGRESS_S if sys.stderr.isatty() else 0.0)

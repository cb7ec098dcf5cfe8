"""``watch`` and ``status`` drawn with rich on a terminal: what the screens hold."""

from __future__ import annotations

import io

from rich.console import Console

from lessmap.cli.screens import status_tables, watch_screen
from lessmap_client.cli_status import render_status, status_report
from lessmap_client.watch import FleetView
from lessmap_schemas.messages import SubmapSummary, Transition


def rendered(renderable: object) -> str:
    console = Console(file=io.StringIO(), width=300, color_system=None, force_terminal=False)
    console.print(renderable)
    text: str = console.file.getvalue()  # type: ignore[attr-defined]
    return text


def a_transition() -> Transition:
    return Transition(
        fleet="warehouse",
        robot="amr-7",
        session="run-1",
        incarnation=0,
        seq=42,
        boundary_seq=38,
        stamp_s=12.5,
        reason="SPECTRAL",
        ncut=0.125,
        lambda2=0.03,
        closed=SubmapSummary(id=0, first_seq=0, last_seq=41, frame_count=40, features=[1, 2]),
        opened=SubmapSummary(id=1, first_seq=38, last_seq=42, frame_count=5, features=[3]),
        boundary_features=[],
        area=1,
        left_area=0,
        revisit=False,
        batch_frames=1,
        instance="demo",
        partition=23,
        epoch=2,
    )


def test_the_watch_screen_has_a_row_per_robot_and_the_latest_transitions() -> None:
    view = FleetView()
    line = view.add_transition(a_transition())
    text = rendered(watch_screen(view, "lessmap watch warehouse"))
    lines = text.splitlines()
    assert lines[0].startswith("lessmap watch warehouse")
    header = lines[1].split()
    assert header[:3] == ["robot", "session", "submap"]
    assert "λ2" in header
    assert lines[2].split()[:6] == ["warehouse/amr-7", "run-1", "1", "1", "-", "1"]
    assert "0.125" in lines[2]
    assert f"  {line}" in text
    assert "\x1b[" not in text  # rich draws; no escape codes of ours


def test_an_empty_watch_screen_says_so() -> None:
    assert "(none yet)" in rendered(watch_screen(FleetView(), "t"))


def test_the_status_tables_hold_what_the_plain_text_holds() -> None:
    report = status_report(["inst-a"], [])
    text = rendered(status_tables(report))
    plain = render_status(report)
    assert text.splitlines()[0].split() == plain.splitlines()[0].split()  # the same columns
    assert text.splitlines()[1].split() == plain.splitlines()[1].split()  # the same row
    assert "inst-a: alive but did not answer the Health query" in text
    for line in plain.splitlines()[3:]:  # the partition lines, as in plain text
        assert line.rstrip() in text

"""Markdown of an evaluation: the ``eval.md`` of ``lessmap eval`` and tables for RESULTS.md."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.evaluation.report.evaluation import EvalReport, MethodResult
    from lessmap.evaluation.scores.consistency import Consistency, Spread
    from lessmap.evaluation.studies.diagnosis import StreamStats


def pct(value: float | None, digits: int = 0) -> str:
    """Format a ratio as a percentage; None as n/a."""
    return "n/a" if value is None else f"{100 * value:.{digits}f}%"


def metres(value: float | None) -> str:
    """Format metres with two decimals; None as n/a."""
    return "n/a" if value is None else f"{value:.2f}"


def table(header: Sequence[str], rows: Sequence[Sequence[object]], align: str = "") -> list[str]:
    """Return the lines of a Markdown table; ``align`` is one of "l"/"r" per column."""
    marks = [":---" if a == "l" else "---:" for a in align.ljust(len(header), "r")]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(marks) + "|"]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return lines


def _spread_cell(result: Consistency, *, passages: bool = False, at: str = "boundary") -> str:
    spread = result.spread(passages=passages, at=at)
    return "n/a" if spread is None else f"{spread[0]:.2f} / {spread[1]:.2f}"


def consistency_lines(results: Sequence[Consistency]) -> list[str]:
    """Return the consistency tables: scores per method, then the doors of the first method."""
    if not results:
        return []
    first = results[0]
    lines = [
        f'Windows ±{first.tolerance_frames} frames; "near a door": boundary frame within '
        f"{first.door_distance_m:g} m of a door centre. Spread: distance between the true "
        "positions of the transition points of repeated crossings of the same door, "
        "mean of the per-door mean pairwise distance / largest pairwise distance (m); "
        '"passage" = same door, same direction.',
        "",
    ]
    header = [
        "method",
        "room changes",
        "transitions",
        "recall",
        "recall (boundary)",
        "recall (any delay)",
        "precision",
        "precision (boundary)",
        "near a door",
        "latency mean / median / max (frames)",
        "spread at boundary, by door (m)",
        "by passage (m)",
        "spread at detection, by door (m)",
    ]
    rows = []
    for r in results:
        latency = (
            "n/a"
            if r.latency_mean is None
            else f"{r.latency_mean:.1f} / {r.latency_median:g} / {r.latency_max}"
        )
        rows.append(
            [
                r.method,
                r.changes,
                r.transitions,
                pct(r.recall),
                pct(r.recall_boundary),
                pct(r.recall_any),
                pct(r.precision),
                pct(r.precision_boundary),
                pct(r.precision_door),
                latency,
                _spread_cell(r),
                _spread_cell(r, passages=True),
                _spread_cell(r, at="seq"),
            ]
        )
    lines += table(header, rows, "l")
    lines += ["", f"Doors, {first.method}:", ""]
    lines += door_lines(first.doors)
    return lines


def door_lines(spreads: Sequence[Spread]) -> list[str]:
    """Return the per-door spread table."""
    header = [
        "door",
        "crossings",
        "with a transition",
        "spread at boundary mean / max (m)",
        "spread at detection mean / max (m)",
        "boundary to door centre (m)",
    ]
    rows = [
        [
            s.door,
            s.crossings,
            s.matched,
            f"{metres(s.boundary_mean_m)} / {metres(s.boundary_max_m)}",
            f"{metres(s.seq_mean_m)} / {metres(s.seq_max_m)}",
            metres(s.boundary_to_door_m),
        ]
        for s in spreads
    ]
    return table(header, rows)


def eval_markdown(
    report: EvalReport,
    consistency: Sequence[Consistency] = (),
    figures: Sequence[str] = (),
) -> str:
    """Return ``eval.md``: the e tables, the consistency section (sim runs), the figures.

    Args:
        report: the information-loss evaluation.
        consistency: scores against the ground truth, LESS-mapping first (empty: no truth).
        figures: PNG file names next to ``eval.md``.
    """
    lines = [report.to_markdown().rstrip()]
    if consistency:
        lines += ["", "## Consistency with the ground truth (all robots)", ""]
        lines += consistency_lines(consistency)
    if figures:
        lines += ["", "## Figures", ""]
        lines += [f"![{name}]({name})" for name in figures]
    return "\n".join(lines) + "\n"


def describe(result: Consistency) -> str:
    """Return one line of consistency figures (what ``lessmap eval`` prints)."""
    latency = "n/a" if result.latency_mean is None else f"{result.latency_mean:.1f}"
    return (
        f"{result.method}: {result.changes} room changes, {result.transitions} transitions; "
        f"recall {pct(result.recall)} (boundary {pct(result.recall_boundary)}), precision "
        f"{pct(result.precision)} (boundary {pct(result.precision_boundary)}), near a door "
        f"{pct(result.precision_door)}, latency {latency} frames, spread at boundary "
        f"{_spread_cell(result)} m (mean/max)"
    )


def e3(value: float) -> str:
    """E as a percentage with three decimals."""
    return f"{100 * value:.3f}"


def e1(value: float) -> str:
    """E as a percentage with one decimal (the exclusive rule's larger values)."""
    return f"{100 * value:.1f}"


def ratio(a: float, b: float) -> str:
    """Describe a/b in words: '1.6× higher than', 'about equal to', '3.0× lower than'."""
    if b == 0.0:
        return "above" if a > 0 else "equal to"
    r = a / b
    if 0.9 <= r <= 1.1:
        return "about equal to"
    return f"{r:.1f}× higher than" if r > 1 else f"{1 / r:.1f}× lower than"


def method(report: EvalReport, prefix: str) -> MethodResult:
    """The first method of the report whose name starts with ``prefix``."""
    return next(m for m in report.methods if m.name.startswith(prefix))


def stream_table(named: Sequence[tuple[str, StreamStats]]) -> list[str]:
    """Return the stream-density table (``diagnosis.StreamStats`` per named stream)."""
    header = [
        "stream",
        "frames",
        "features per frame mean / median",
        "empty frames",
        "frames per landmark (median)",
        "frames a landmark stays in view mean / median",
    ]
    rows = [
        [
            name,
            s.frames,
            f"{s.features_mean:.1f} / {s.features_median:g}",
            pct(s.empty_share, 1),
            f"{s.sightings_median:g}",
            f"{s.run_mean:.1f} / {s.run_median:g}",
        ]
        for name, s in named
    ]
    return table(header, rows, "l")

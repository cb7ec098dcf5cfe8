"""Figures of the results: transition points in a simulated building, e against submap count.

Built on ``matplotlib.figure.Figure`` without pyplot, as
``lessmap.evaluation.figures.segmentation``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    from lessmap.evaluation.scores.consistency import Detection
    from lessmap.sim.simulator import SimTruth

DPI = 100
_MARKERS = {"SPECTRAL": "o", "DISCONNECTED": "x", "FIXED": "^"}


def consistency_figure(truth: SimTruth, detections: Mapping[str, Sequence[Detection]]) -> Figure:
    """Draw the building, the true paths and each method's transition points (one panel each).

    A point is the robot's true position at the transition's ``boundary_seq``; a method
    whose partitions follow the environment puts them in the door openings.
    """
    where = truth.positions()
    count = max(len(detections), 1)
    fig = Figure(figsize=(6.0 * count, 5.0), dpi=DPI)
    axes = fig.subplots(1, count, squeeze=False)[0]
    for ax, (method, found) in zip(axes, detections.items(), strict=False):
        for x0, y0, x1, y1 in truth.walls:
            ax.plot([x0, x1], [y0, y1], color="black", linewidth=1.2)
        for robot in sorted({row.robot for row in truth.rows}):
            path = sorted((row.seq, row.x, row.y) for row in truth.rows if row.robot == robot)
            ax.plot([p[1] for p in path], [p[2] for p in path], color="0.85", linewidth=0.5)
        for door in truth.doors:
            ax.scatter(
                [door.x],
                [door.y],
                marker="s",
                s=60,
                facecolors="none",
                edgecolors="tab:green",
                linewidths=1.2,
                zorder=3,
            )
        for reason in sorted({d.reason for d in found}):
            xy = [where[(d.robot, d.boundary_seq)] for d in found if d.reason == reason]
            ax.scatter(
                [p[0] for p in xy],
                [p[1] for p in xy],
                marker=_MARKERS.get(reason, "o"),
                s=18,
                color="tab:red" if reason != "FIXED" else "tab:blue",
                alpha=0.7,
                zorder=4,
                label=f"{reason.lower()} ({len(xy)})",
            )
        ax.set_title(f"{method}: transition points (boundary frame)", fontsize="medium")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m); green squares: doors")
        ax.set_ylabel("y (m)")
        if found:
            ax.legend(loc="upper right", fontsize="x-small")
    return fig


def write_consistency_figure(
    path: Path, truth: SimTruth, detections: Mapping[str, Sequence[Detection]]
) -> Path:
    """Write ``consistency_figure`` as PNG; return the path."""
    consistency_figure(truth, detections).savefig(path, format="png", bbox_inches="tight")
    return path


def loss_count_figure(
    series: Mapping[str, Sequence[tuple[int, float, float]]], title: str = ""
) -> Figure:
    """Plot e against the number of submaps, per method (log-log), for both membership rules.

    Args:
        series: method → points (submaps, e, e_exclusive); e as ratios.
        title: figure title.
    """
    fig = Figure(figsize=(11.0, 4.5), dpi=DPI)
    axes = fig.subplots(1, 2)
    styles = ["o-", "s--", "^:", "D-.", "v-", "P--"]
    for ax, column, label in (
        (axes[0], 1, "e (%): a landmark in every submap that saw it"),
        (axes[1], 2, "e exclusive (%): a landmark in one submap"),
    ):
        for (name, points), style in zip(series.items(), styles * 4, strict=False):
            ordered = sorted(points)
            xs = [p[0] for p in ordered]
            ys = [100 * p[column] for p in ordered]
            connect = style if name.startswith("fixed") else style[0]
            ax.plot(xs, ys, connect, markersize=4, linewidth=1.0, label=name)
        ax.set_xscale("log")
        ax.set_yscale("log")
        plain = FuncFormatter(lambda value, _: f"{value:g}")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(plain)
            axis.set_minor_formatter(FuncFormatter(lambda _v, _p: ""))
        ax.set_xlabel("submaps")
        ax.set_ylabel(label)
        ax.grid(visible=True, which="both", linewidth=0.3)
    axes[0].legend(fontsize="x-small", loc="lower right")
    if title:
        fig.suptitle(title, fontsize="medium")
    return fig

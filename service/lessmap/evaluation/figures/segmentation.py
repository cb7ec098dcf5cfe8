"""Figures of a segmentation (PNG): trajectory, Ncut/λ2 over frames, reordered W, sweep.

Figures are built on ``matplotlib.figure.Figure`` directly, never through pyplot, so no
global backend or figure registry is touched; ``Figure.savefig`` renders with Agg.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from lessmap.core import CovGraph, Reason
from lessmap.evaluation.scores.infoloss import landmark_submaps

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from numpy.typing import NDArray

    from lessmap.evaluation.data.segmentation import LessmapRun
    from lessmap.evaluation.studies.sweep import SweepRow
    from lessmap.files.frames import FrameRow

_CYCLE = 20  # submap colours repeat after this many (the tab20 palette)
_DPI = 120


def submap_colours(labels: NDArray[np.int64]) -> NDArray[np.float64]:
    """Return an RGBA colour per label from the cyclic tab20 palette, shape (k, 4)."""
    rgba: NDArray[np.float64] = colormaps["tab20"](np.asarray(labels) % _CYCLE)
    return rgba


def trajectory_figure(frames: Sequence[FrameRow], run: LessmapRun) -> Figure | None:
    """Plot the poses coloured by submap, with transition markers; None without poses."""
    poses = [frame.pose for frame in frames]
    if any(pose is None for pose in poses):
        return None
    xy = np.asarray(poses, dtype=np.float64)[:, :2]
    fig = Figure(figsize=(8, 7), dpi=_DPI)
    ax = fig.add_subplot()
    ax.plot(xy[:, 0], xy[:, 1], color="0.85", linewidth=0.8, zorder=1)
    ax.scatter(xy[:, 0], xy[:, 1], c=submap_colours(run.labels), s=4, zorder=2)
    index_of_seq = {frame.seq: i for i, frame in enumerate(frames)}
    spectral = [
        index_of_seq[t.boundary_seq] for t in run.transitions if t.reason is Reason.SPECTRAL
    ]
    disconnected = [
        index_of_seq[t.boundary_seq] for t in run.transitions if t.reason is Reason.DISCONNECTED
    ]
    if spectral:
        ax.scatter(
            xy[spectral, 0],
            xy[spectral, 1],
            marker="o",
            s=40,
            facecolors="none",
            edgecolors="black",
            zorder=3,
            label="transition (Eq. 4)",
        )
    if disconnected:
        ax.scatter(
            xy[disconnected, 0],
            xy[disconnected, 1],
            marker="x",
            s=40,
            c="black",
            zorder=3,
            label="transition (disconnected)",
        )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    count = int(run.labels.max()) + 1 if run.labels.size else 0
    ax.set_title(
        f"{count} submaps (Ncut ≤ {run.params.ncut_min:g}, λ2 ≤ {run.params.lambda2_min:g}); "
        "markers at each new submap's first frame"
    )
    if run.transitions:
        ax.legend(loc="best", fontsize="small")
    return fig


def thresholds_figure(run: LessmapRun) -> Figure:
    """Plot Ncut and λ2 of every decision over the frames, with the thresholds of Eq. 4."""
    fig = Figure(figsize=(11, 6), dpi=_DPI)
    axes = fig.subplots(2, 1, sharex=True)
    values = [(e.seq, e.ncut, e.lambda2) for e in run.evaluations if e.ncut is not None]
    seqs = np.asarray([v[0] for v in values], dtype=np.float64)
    for ax, column, name, threshold in (
        (axes[0], 1, "Ncut", run.params.ncut_min),
        (axes[1], 2, "λ2", run.params.lambda2_min),
    ):
        ys = np.asarray([v[column] for v in values], dtype=np.float64)
        ax.plot(seqs, ys, linewidth=0.6, color="tab:blue")
        ax.axhline(threshold, color="tab:red", linewidth=1.0, label=f"{name}_min = {threshold:g}")
        for t in run.transitions:
            style = "-" if t.reason is Reason.SPECTRAL else ":"
            ax.axvline(t.seq, color="0.6", linewidth=0.5, linestyle=style)
        ax.set_ylabel(name)
        ax.set_ylim(bottom=0.0)
        ax.legend(loc="upper right", fontsize="small")
    axes[1].set_xlabel("frame seq (grey: transitions; dotted: disconnected CovGraph)")
    axes[0].set_title("Spectral test at every decision (transition when both are below)")
    return fig


def similarity_figure(frames: Sequence[FrameRow], labels: NDArray[np.int64]) -> Figure:
    """Plot W (CovRate over all frames) with features ordered by submap, then first sighting.

    Each feature is placed in the submap that observed it most often, so a segmentation that
    follows the environment shows as a block-diagonal W; block edges are drawn.
    """
    graph = CovGraph()
    for frame in frames:
        graph.add_frame(frame.seq, frame.features)
    w = graph.covrate().toarray()
    ids = graph.feature_ids
    owner = landmark_submaps([f.features for f in frames], labels, exclusive=True)
    primary = np.asarray([min(owner[int(i)]) for i in ids], dtype=np.int64)
    order = np.lexsort((np.asarray(graph.first_seen), primary))
    fig = Figure(figsize=(8, 7), dpi=_DPI)
    ax = fig.add_subplot()
    image = ax.imshow(
        w[np.ix_(order, order)], cmap="magma_r", vmin=0.0, vmax=1.0, interpolation="nearest"
    )
    edges = np.flatnonzero(np.diff(primary[order])) + 0.5
    width = 0.6 if edges.size <= 40 else 0.2  # many blocks: keep W visible under the grid
    for edge in edges:
        ax.axhline(edge, color="tab:cyan", linewidth=width, alpha=0.6)
        ax.axvline(edge, color="tab:cyan", linewidth=width, alpha=0.6)
    fig.colorbar(image, ax=ax, label="CovRate W_ij")
    ax.set_title(
        f"W of {ids.size} features, each in the submap that saw it most ({edges.size + 1} blocks)"
    )
    ax.set_xlabel("feature (by submap)")
    ax.set_ylabel("feature (by submap)")
    return fig


def sweep_figure(rows: Sequence[SweepRow]) -> Figure:
    """Plot e (%) over the (Ncut_min, λ2_min) grid, each cell annotated with its submaps."""
    ncuts = sorted({row.ncut_min for row in rows})
    lams = sorted({row.lambda2_min for row in rows})
    grid = np.full((len(lams), len(ncuts)), np.nan)
    counts = np.zeros((len(lams), len(ncuts)), dtype=np.int64)
    for row in rows:
        i, j = lams.index(row.lambda2_min), ncuts.index(row.ncut_min)
        grid[i, j] = 100.0 * row.e
        counts[i, j] = row.stats.submaps
    fig = Figure(figsize=(1.4 * len(ncuts) + 3, 1.1 * len(lams) + 2), dpi=_DPI)
    ax = fig.add_subplot()
    image = ax.imshow(grid, origin="lower", cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(ncuts)), [f"{v:g}" for v in ncuts])
    ax.set_yticks(range(len(lams)), [f"{v:g}" for v in lams])
    ax.set_xlabel("Ncut_min")
    ax.set_ylabel("λ2_min")
    low, high = np.nanmin(grid), np.nanmax(grid)
    for i in range(len(lams)):
        for j in range(len(ncuts)):
            if np.isfinite(grid[i, j]):
                bright = high > low and (grid[i, j] - low) / (high - low) > 0.6  # viridis: yellow
                ax.text(
                    j,
                    i,
                    f"{grid[i, j]:.2f}%\n{counts[i, j]} maps",
                    ha="center",
                    va="center",
                    fontsize="x-small",
                    color="black" if bright else "white",
                )
    fig.colorbar(image, ax=ax, label="information loss e (%)")
    ax.set_title("Threshold sweep: e and submap count")
    return fig


def write_plots(
    out_dir: Path,
    frames: Sequence[FrameRow],
    run: LessmapRun,
    rows: Sequence[SweepRow] = (),
) -> list[Path]:
    """Write the PNGs of one run (and of the sweep, when given); return their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    figures: dict[str, Figure | None] = {
        "trajectory.png": trajectory_figure(frames, run),
        "ncut_lambda2.png": thresholds_figure(run),
        "similarity.png": similarity_figure(frames, run.labels),
        "sweep.png": sweep_figure(rows) if rows else None,
    }
    written = []
    for name, fig in figures.items():
        if fig is None:
            continue
        path = out_dir / name
        fig.savefig(path, format="png", bbox_inches="tight")
        written.append(path)
    return written

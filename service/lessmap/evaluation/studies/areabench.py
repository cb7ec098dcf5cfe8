"""Paper vs areas on every criterion: ``python -m lessmap.evaluation.studies.areabench``.

Prints one table per criterion, each method side by side: simulated buildings (seeds from
``--first-seed``; 5 gives held-out seeds to check a tuning on) for recall, precision,
latency and revisits; one open area and the MRCLAM sets for transitions per robot per 10
minutes; closed submaps below 5 features; dlr's e against fixed frames. The data sets are
read from ``--datasets`` (default ``../shared/datasets``); a missing one is reported and
skipped. Details: ``docs/design/evaluation.md``; the tuning it measured:
``docs/tuning/areas.md``.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lessmap.core.areas.params import AreaParams
from lessmap.evaluation.baselines import fixed_frames
from lessmap.evaluation.methods import (
    AreaEvent,
    RevisitScore,
    add_spans_in_views_option,
    dataset_area_params,
    revisit_score,
    run_method,
)
from lessmap.evaluation.scores.infoloss import (
    information_loss,
    landmark_information,
    landmark_submaps,
)
from lessmap.files.frames import FrameRow, read_frames
from lessmap.sim.groundtruth import Score, score
from lessmap.sim.simulator import simulate

#: The methods this study compares (its targets are those of ``areas``).
METHODS = ("paper", "areas")

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

TOLERANCE_FRAMES = 8
TINY_FEATURES = 5  # a closed submap below this many features is a fragment
SPARSE_SPACING_M = (2.0, 3.5)  # wall landmarks every 2-3.5 m instead of 0.6-1.2 m
OPEN_ROOMS_M = {"8-10 m": (8.0, 10.0), "12-16 m": (12.0, 16.0)}  # sides drawn in these ranges


@dataclass(slots=True)
class Tally:
    """Transitions, fragments and the span of the streams they came from."""

    transitions: int = 0
    tiny: int = 0
    robots: int = 0
    minutes: float = 0.0

    def add(self, events: dict[str, list[AreaEvent]], frames: Sequence[FrameRow]) -> None:
        """Count one run's events; its span is each robot's first to last stamp."""
        spans: dict[str, list[float]] = {}
        for frame in frames:
            spans.setdefault(frame.robot, []).append(frame.stamp_s)
        self.robots += len(spans)
        self.minutes += sum((max(s) - min(s)) / 60.0 for s in spans.values())
        for found in events.values():
            self.transitions += len(found)
            self.tiny += sum(event.closed_features < TINY_FEATURES for event in found)

    @property
    def per_robot_10min(self) -> float:
        """Transitions per robot per 10 minutes."""
        return 10.0 * self.transitions / self.minutes if self.minutes else math.nan


@dataclass(slots=True)
class SimResult:
    """One method on a family of simulated buildings."""

    score: Score
    revisits: RevisitScore
    tally: Tally = field(default_factory=Tally)


def rows(run_frames: list[dict[str, Any]]) -> list[FrameRow]:
    """The simulator's frame dicts as frames-file rows."""
    return [
        FrameRow(str(f["robot"]), int(f["seq"]), float(f["stamp"]), tuple(f["features"]), None)
        for f in run_frames
    ]


def sim_buildings(
    seeds: int, first_seed: int = 0, *, areas: AreaParams | None = None, **options: Any
) -> dict[str, SimResult]:
    """Score both methods on ``seeds`` simulated 8-room buildings (robots kept apart)."""
    changes: list[dict[str, Any]] = []
    found: dict[str, dict[str, list[AreaEvent]]] = {m: {} for m in METHODS}
    revisits = {m: RevisitScore(visits=0, revisits=0, recognised=0, false=0) for m in METHODS}
    tallies = {m: Tally() for m in METHODS}
    for seed in range(first_seed, first_seed + seeds):
        run = simulate(seed, rooms=8, robots=3, frames_per_robot=1000, **options)
        frames = rows(run.frames)
        changes += [{"robot": f"{seed}/{c.robot}", "seq": c.seq} for c in run.room_changes]
        for method in METHODS:
            events = run_method(frames, method, areas=areas)
            tallies[method].add(events, frames)
            revisits[method] += revisit_score(run.truth, events)
            found[method] |= {f"{seed}/{robot}": items for robot, items in events.items()}
    return {
        m: SimResult(
            score(changes, found[m], tolerance_frames=TOLERANCE_FRAMES), revisits[m], tallies[m]
        )
        for m in METHODS
    }


def open_area(
    seeds: int, first_seed: int = 0, *, areas: AreaParams | None = None, **options: Any
) -> dict[str, Tally]:
    """Transitions of both methods in one doorless room, ``seeds`` runs of 3 robots."""
    tallies = {m: Tally() for m in METHODS}
    for seed in range(first_seed, first_seed + seeds):
        run = simulate(seed, rooms=1, robots=3, frames_per_robot=1000, **options)
        frames = rows(run.frames)
        for method in METHODS:
            tallies[method].add(run_method(frames, method, areas=areas), frames)
    return tallies


def dataset_tally(path: Path, areas: AreaParams | None = None) -> dict[str, Tally]:
    """Transitions and fragments of both methods on a recorded frames file."""
    frames = list(read_frames(path))
    tallies = {m: Tally() for m in METHODS}
    params = dataset_area_params(path, areas)
    for method in METHODS:
        tallies[method].add(run_method(frames, method, areas=params), frames)
    return tallies


def _segments(seqs: Sequence[int], events: Sequence[AreaEvent]) -> NDArray[np.int64]:
    starts = np.sort(np.asarray([e.boundary_seq for e in events], dtype=np.int64))
    labels: NDArray[np.int64] = np.searchsorted(starts, np.asarray(seqs), side="right")
    return labels.astype(np.int64)


def _areas(seqs: Sequence[int], events: Sequence[AreaEvent]) -> NDArray[np.int64]:
    from lessmap.evaluation.methods import area_of_frames

    return np.asarray(area_of_frames(seqs, events), dtype=np.int64)


@dataclass(frozen=True, slots=True)
class LossRow:
    """e of one segmentation and of fixed frames cut to the same number of submaps."""

    name: str
    submaps: int
    e: float
    e_fixed: float
    e_exclusive: float
    e_exclusive_fixed: float


def dlr_loss(path: Path, areas: AreaParams | None = None) -> list[LossRow]:
    """Return e on dlr of each method's segments (areas also merged) and of fixed frames."""
    from lessmap.evaluation.data.dataset import load_dataset

    dataset = load_dataset(path, None)
    frames = dataset.frames
    features = [frame.features for frame in frames]
    seqs = [frame.seq for frame in frames]
    info = landmark_information(dataset.problem)

    def loss(labels: NDArray[np.int64], exclusive: bool) -> float:
        return information_loss(info, landmark_submaps(features, labels, exclusive=exclusive))

    out: list[LossRow] = []
    for method in METHODS:
        events = run_method(frames, method, areas=areas).get(dataset.robot, [])
        labelings = [(method, _segments(seqs, events))]
        if method == "areas":
            labelings.append(("areas, revisits merged", _areas(seqs, events)))
        for name, labels in labelings:
            count = len(np.unique(labels))
            fixed = fixed_frames(features, max(1, math.ceil(len(frames) / count)))
            out.append(
                LossRow(
                    name,
                    count,
                    loss(labels, False),
                    loss(fixed, False),
                    loss(labels, True),
                    loss(fixed, True),
                )
            )
    return out


def _pct(value: float | None, digits: int = 0) -> str:
    return "n/a" if value is None else f"{100 * value:.{digits}f}%"


def report(
    seeds: int, datasets: Path, first_seed: int = 0, params: AreaParams | None = None
) -> str:
    """Measure everything and return the tables as Markdown (``params``: the areas')."""
    last_seed = first_seed + seeds - 1
    lines = [
        f"simulated buildings: 8 rooms, 3 robots, 1000 frames each, seeds {first_seed}-"
        f"{last_seed}; "
        f"windows ±{TOLERANCE_FRAMES} frames",
        "",
        "| building | method | changes | transitions | recall | precision | latency mean "
        "| revisits recognised | false area names | closed < 5 features |",
        "|:---|:---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    cases: dict[str, dict[str, Any]] = {
        "270°, dense": {"fov_deg": 270.0},
        "360°, dense": {"fov_deg": 360.0},
        "270°, sparse": {"fov_deg": 270.0, "landmark_spacing_m": SPARSE_SPACING_M},
        "360°, sparse": {"fov_deg": 360.0, "landmark_spacing_m": SPARSE_SPACING_M},
    }
    buildings: dict[str, dict[str, SimResult]] = {}
    for case, options in cases.items():
        buildings[case] = sim_buildings(seeds, first_seed, areas=params, **options)
        for method, result in buildings[case].items():
            s, r = result.score, result.revisits
            latency = "n/a" if s.latency_mean is None else f"{s.latency_mean:.1f}"
            lines.append(
                f"| {case} | {method} | {s.changes} | {s.transitions} | {_pct(s.recall)} | "
                f"{_pct(s.precision)} | {latency} | {r.recognised}/{r.revisits} "
                f"({_pct(r.recognised_share)}) | {r.false}/{r.visits} "
                f"({_pct(r.false_share, 1)}) | {result.tally.tiny} |"
            )
    lines += [
        "",
        "one area: transitions per robot per 10 minutes",
        "",
        "| stream | method | robots | minutes | transitions | per robot per 10 min "
        "| closed < 5 features |",
        "|:---|:---|---:|---:|---:|---:|---:|",
    ]
    areas: dict[str, dict[str, Tally]] = {}
    open_cases: dict[str, dict[str, Any]] = {}
    for size, sides in OPEN_ROOMS_M.items():
        open_cases |= {
            f"sim open room {size}, 270°, dense": {"fov_deg": 270.0, "room_size_m": sides},
            f"sim open room {size}, 360°, dense": {"fov_deg": 360.0, "room_size_m": sides},
            f"sim open room {size}, 270°, sparse": {
                "fov_deg": 270.0,
                "room_size_m": sides,
                "landmark_spacing_m": SPARSE_SPACING_M,
            },
        }
    for name, options in open_cases.items():
        areas[name] = open_area(seeds, first_seed, areas=params, **options)
    for name in ("mrclam6", "mrclam1_w1s", "dlr"):
        path = datasets / f"{name}.frames.jsonl"
        if path.is_file():
            areas[name] = dataset_tally(path, params)
        else:
            lines.append(f"({path} not found: skipped)")
    for name, tallies in areas.items():
        for method, t in tallies.items():
            lines.append(
                f"| {name} | {method} | {t.robots} | {t.minutes:.0f} | {t.transitions} | "
                f"{t.per_robot_10min:.2f} | {t.tiny} |"
            )
    dlr = datasets / "dlr.frames.jsonl"
    losses = dlr_loss(dlr, params) if dlr.is_file() else []
    if losses:
        lines += [
            "",
            "dlr: e (Eq. 5) against fixed frames cut to the same number of submaps",
            "",
            "| segmentation | submaps | e | e fixed frames | e exclusive | "
            "e exclusive fixed frames |",
            "|:---|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {row.name} | {row.submaps} | {_pct(row.e, 3)} | {_pct(row.e_fixed, 3)} | "
            f"{_pct(row.e_exclusive, 1)} | {_pct(row.e_exclusive_fixed, 1)} |"
            for row in losses
        ]
    lines += ["", "targets of the areas method:", ""]
    lines += verdicts(buildings, areas, losses)
    return "\n".join(lines) + "\n"


def _mark(ok: bool) -> str:
    return "met" if ok else "missed"


def revisits_met(score: RevisitScore) -> bool:
    """The revisit target: ≥ 90% recognised, ≤ 2% false names (a 0% counts)."""
    recognised, false = score.recognised_share, score.false_share
    return recognised is not None and recognised >= 0.9 and false is not None and false <= 0.02


def verdicts(
    buildings: dict[str, dict[str, SimResult]],
    areas: dict[str, dict[str, Tally]],
    losses: list[LossRow],
) -> list[str]:
    """Return one line per target: met or missed, with the measured figures."""
    out = []
    for case, results in buildings.items():
        s, r = results["areas"].score, results["areas"].revisits
        ok = (s.recall or 0) >= 0.95 and (s.precision or 0) >= 0.95
        out.append(
            f"- {case}: recall and precision ≥ 95%: {_mark(ok)} ({_pct(s.recall)} / "
            f"{_pct(s.precision)}); revisits ≥ 90% recognised, ≤ 2% false: "
            f"{_mark(revisits_met(r))} "
            f"({_pct(r.recognised_share)} / {_pct(r.false_share, 1)})"
        )
    for name, tallies in areas.items():
        if name.startswith("sim open room") or name == "mrclam6":
            rate = tallies["areas"].per_robot_10min
            out.append(
                f"- {name}: ≤ 1 transition per robot per 10 min: {_mark(rate <= 1.0)} "
                f"({rate:.2f}; paper {tallies['paper'].per_robot_10min:.2f})"
            )
    tiny = sum(t["areas"].tiny for t in areas.values())
    tiny += sum(r["areas"].tally.tiny for r in buildings.values())
    out.append(f"- no closed submap below 5 features: {_mark(tiny == 0)} ({tiny} found)")
    for row in losses:
        if row.name == "areas":
            out.append(
                f"- dlr: e at equal count no worse than fixed frames: "
                f"{_mark(row.e <= row.e_fixed)} ({_pct(row.e, 3)} vs {_pct(row.e_fixed, 3)}; "
                f"e exclusive {_pct(row.e_exclusive, 1)} vs {_pct(row.e_exclusive_fixed, 1)})"
            )
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables (``python -m lessmap.evaluation.studies.areabench --help``)."""
    parser = argparse.ArgumentParser(prog="python -m lessmap.evaluation.studies.areabench")
    parser.add_argument("--seeds", type=int, default=5, help="simulated runs per case")
    parser.add_argument(
        "--first-seed", type=int, default=0, help="seed of the first simulated run (default 0)"
    )
    parser.add_argument(
        "--datasets", type=Path, default=Path("../shared/datasets"), help="data set folder"
    )
    add_spans_in_views_option(parser)
    args = parser.parse_args(argv)
    params = AreaParams(spans_in_views=args.spans_in_views)
    sys.stdout.write(report(args.seeds, args.datasets, args.first_seed, params))
    return 0


if __name__ == "__main__":
    sys.exit(main())

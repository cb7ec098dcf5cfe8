"""The floor-plan benchmark: ``python -m lessmap.floorplan.bench`` (``--help`` for options).

For every case (map x sensor x seed x frame rate) a simulator writes a run (frames with
poses, each frame's true room, the occupancy map and its ground-truth rooms); each method
segments the frames, one robot at a time, and is scored on the stream and on its room maps
(per robot, and the fleet's merged map): ``lessmap.floorplan.metric``, ``.roommap``.

Methods: ``areas``, ``paper`` (default parameters); ``fixed`` cuts every N frames, N = a
robot's frames / (its true changes + 1): it is told the true count. References without a
stream: ``truth`` labels the walk with the true rooms (the best room map this walk gives),
``geometry`` is the doorway regions alone (the map without any segmentation).

Cases run in ``--jobs`` processes; the simulator is ``building`` (default), ``floorplan``
(the benchmark's maps) or ``MODULE:FUNCTION``, a ``Simulator`` (``.simcases``).
"""

from __future__ import annotations

import argparse
import importlib
import math
import statistics
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from itertools import product
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from threadpoolctl import threadpool_limits

from lessmap.core.areas.params import AreaParams
from lessmap.evaluation.methods import add_spans_in_views_option
from lessmap.files.frames import read_frames
from lessmap.floorplan.command import add_room_map_options, room_map_params
from lessmap.floorplan.grid import FloorplanError, load_grid, room_labels
from lessmap.floorplan.metric import PrecisionRecall, StreamScore, precision_recall, stream_score
from lessmap.floorplan.roommap import (
    RoomMapParams,
    merged_room_map,
    nearest_samples,
    passage_regions,
    room_map,
)
from lessmap.floorplan.simcases import (
    BenchCase,
    FloorplanSimulator,
    SimulatedRun,
    Simulator,
    building_run,
)
from lessmap.floorplan.streams import (
    fixed_cuts,
    frame_areas,
    method_cuts,
    read_poses,
    read_tracks,
)
from lessmap.progress import NO_PROGRESS, tracked

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

    from lessmap.floorplan.metric import Cut, Track
    from lessmap.progress import Progress

METHODS = ("areas", "rooms", "paper", "fixed")
SIMULATORS: dict[str, Simulator] = {"building": building_run}


@dataclass(frozen=True, slots=True, kw_only=True)
class MethodResult:
    """One method on one case."""

    method: str
    stream: StreamScore | None  # None for the references
    robot_maps: tuple[PrecisionRecall, ...]  # one per robot
    fleet_map: PrecisionRecall


@dataclass(frozen=True, slots=True, kw_only=True)
class CaseResult:
    """Every method on one case."""

    case: BenchCase
    results: tuple[MethodResult, ...] = field(default=())


def evaluate_case(
    simulator: Simulator,
    case: BenchCase,
    folder: Path,
    methods: Sequence[str] = METHODS,
    params: RoomMapParams | None = None,
    tolerance_m: float = 1.0,
    areas: AreaParams | None = None,
) -> CaseResult:
    """Simulate one case into ``folder`` and score every method on it (``areas``' params)."""
    params = params or RoomMapParams()
    run: SimulatedRun = simulator(case, folder)
    grid = load_grid(run.grid_map, run.resolution_m)
    truth_rooms = room_labels(run.labels, grid.resolution_m, min_room_m2=0.0)
    if truth_rooms.shape != grid.shape:
        msg = f"{run.labels}: {truth_rooms.shape} pixels, the map {run.grid_map} {grid.shape}"
        raise FloorplanError(msg)
    frames = list(read_frames(run.frames))
    poses = read_poses(frames, str(run.frames))
    tracks = read_tracks(run.truth)
    robots = sorted(poses)
    missing = [robot for robot in robots if robot not in tracks]
    if missing:
        msg = f"{run.truth}: no truth for robot(s) {', '.join(missing)}"
        raise FloorplanError(msg)
    regions = passage_regions(grid, params)
    fields = [nearest_samples(grid, poses[r].xy, params) for r in robots]
    everyone = nearest_samples(grid, np.concatenate([poses[r].xy for r in robots]), params)

    def maps(
        labels: list[NDArray[np.int64]],
    ) -> tuple[tuple[PrecisionRecall, ...], PrecisionRecall]:
        own = tuple(
            precision_recall(room_map(f, a, regions, params), truth_rooms)
            for f, a in zip(fields, labels, strict=True)
        )
        fleet = merged_room_map(fields, everyone, labels, regions, params)
        return own, precision_recall(fleet, truth_rooms)

    results = []
    for method in methods:
        if method == "fixed":
            cuts: dict[str, list[Cut]] = {}
            for robot in robots:
                changes = int(np.count_nonzero(np.diff(tracks[robot].rooms)))
                length = max(1, round(poses[robot].seqs.size / (changes + 1)))
                cuts[robot] = fixed_cuts(poses[robot].seqs, length)
        else:
            cuts = method_cuts(frames, method, areas)
        stream = StreamScore()
        for robot in robots:
            stream += stream_score(tracks[robot], cuts.get(robot, []), tolerance_m)
        labels = [frame_areas(poses[r].seqs, cuts.get(r, [])) + 1 for r in robots]
        own, fleet = maps(labels)
        results.append(MethodResult(method=method, stream=stream, robot_maps=own, fleet_map=fleet))
    true_labels = [_true_rooms(poses[r].seqs, tracks[r]) for r in robots]
    own, fleet = maps(true_labels)
    results.append(MethodResult(method="truth", stream=None, robot_maps=own, fleet_map=fleet))
    if regions is not None:
        geometry = precision_recall(regions.doorways, truth_rooms)
        results.append(
            MethodResult(method="geometry", stream=None, robot_maps=(geometry,), fleet_map=geometry)
        )
    return CaseResult(case=case, results=tuple(results))


def _true_rooms(seqs: NDArray[np.int64], track: Track) -> NDArray[np.int64]:
    """Each frame's true room as a label >= 1, by seq."""
    index = np.clip(np.searchsorted(track.seqs, seqs), 0, track.seqs.size - 1)
    rooms: NDArray[np.int64] = track.rooms[index] - track.rooms.min() + 1
    return rooms


def _work(
    job: tuple[Simulator, BenchCase, Path, tuple[str, ...], RoomMapParams, float, AreaParams],
) -> CaseResult:
    simulator, case, root, methods, params, tolerance_m, areas = job
    folder = root / case.name
    folder.mkdir(parents=True, exist_ok=True)
    # BLAS on one thread: the cases already run in --jobs processes, and OpenBLAS threads
    # on top of them fight over the cores for factorizations too small to share
    with threadpool_limits(limits=1):
        return evaluate_case(simulator, case, folder, methods, params, tolerance_m, areas)


def run_bench(
    simulator: Simulator,
    cases: Sequence[BenchCase],
    *,
    methods: Sequence[str] = METHODS,
    params: RoomMapParams | None = None,
    tolerance_m: float = 1.0,
    jobs: int = 1,
    work_dir: Path | None = None,
    progress: Progress = NO_PROGRESS,
    areas: AreaParams | None = None,
) -> list[CaseResult]:
    """Run every case (in ``jobs`` processes) and return the results in case order.

    The runs' files go to ``work_dir`` (kept), or to a temporary folder (removed);
    ``progress`` counts the cases done; ``areas`` are the ``areas`` method's parameters.
    """
    params = params or RoomMapParams()
    areas = areas or AreaParams()
    progress.stage(f"{len(cases)} cases", len(cases))
    with tempfile.TemporaryDirectory(prefix="lessmap-floorplan-") as scratch:
        root = work_dir or Path(scratch)
        job = (tuple(methods), params, tolerance_m, areas)
        work = [(simulator, case, root, *job) for case in cases]
        if jobs <= 1 or len(work) <= 1:
            return list(tracked((_work(job) for job in work), progress))
        with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
            return list(tracked(pool.map(_work, work), progress))


@dataclass(slots=True)
class Row:
    """Pooled figures of one method over a set of cases."""

    stream: StreamScore | None = None
    robot_maps: list[PrecisionRecall] = field(default_factory=list)
    fleet_maps: list[PrecisionRecall] = field(default_factory=list)

    def add(self, result: MethodResult) -> None:
        """Pool one case's result."""
        if result.stream is not None:
            self.stream = result.stream if self.stream is None else self.stream + result.stream
        self.robot_maps.extend(result.robot_maps)
        self.fleet_maps.append(result.fleet_map)


#: What the rows of the tables may group cases by: a field of ``BenchCase``.
GROUPS = ("map", "sensor", "seed", "rate_hz")


def summarise(results: Sequence[CaseResult], by: str = "map") -> dict[str, dict[str, Row]]:
    """Pool the results per value of ``by`` and over all cases (key ``all``), per method."""
    if by not in GROUPS:
        msg = f"cannot group by {by!r}; choose one of {', '.join(GROUPS)}"
        raise ValueError(msg)
    table: dict[str, dict[str, Row]] = {}
    for result in results:
        for scope in (_group(result.case, by), "all"):
            for item in result.results:
                table.setdefault(scope, {}).setdefault(item.method, Row()).add(item)
    if "all" in table:
        table["all"] = table.pop("all")  # last
    return table


def _group(case: BenchCase, by: str) -> str:
    value = getattr(case, by)
    return f"{value:g} Hz" if by == "rate_hz" else str(value)


def _mean(values: list[float]) -> float | None:
    kept = [v for v in values if not math.isnan(v)]
    return statistics.fmean(kept) if kept else None


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f}"


def _pair(a: float | None, b: float | None) -> str:
    return f"{_pct(a)} / {_pct(b)}"


def markdown(results: Sequence[CaseResult], tolerance_m: float, by: str = "map") -> str:
    """The benchmark's table as Markdown: one row per ``by`` value and method, then all."""
    lines = [
        f"| {by} | method | boundary R / P | decision R / P | lag m | purity | coverage "
        "| revisits right | cuts / 100 m (true) | robot map P / R | fleet map P / R |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scope, rows in summarise(results, by).items():
        for method, row in rows.items():
            robot_p = _mean([m.precision for m in row.robot_maps])
            robot_r = _mean([m.recall for m in row.robot_maps])
            fleet_p = _mean([m.precision for m in row.fleet_maps])
            fleet_r = _mean([m.recall for m in row.fleet_maps])
            if row.stream is None:
                stream = ["–"] * 7
            else:
                f = row.stream.figures()
                lag = f["decision_lag_m"]
                cuts, true = f["transitions_per_100m"], f["changes_per_100m"]
                stream = [
                    _pair(f["boundary_recall"], f["boundary_precision"]),
                    _pair(f["decision_recall"], f["decision_precision"]),
                    "–" if lag is None else f"{lag:.2f}",
                    _pct(f["purity"]),
                    _pct(f["coverage"]),
                    f"{_pct(f['revisit_accuracy'])} ({row.stream.revisits})",
                    "–" if cuts is None or true is None else f"{cuts:.1f} ({true:.1f})",
                ]
            cells = [scope, method, *stream, _pair(robot_p, robot_r), _pair(fleet_p, fleet_r)]
            lines.append("| " + " | ".join(cells) + " |")
    cases = len(results)
    header = (
        f"{cases} case(s); matches within {tolerance_m:g} m; percentages; lag: median metres "
        "walked from the true change to the decision; revisits: share right (count); "
        "room maps: the benchmark's per-room means, precision / recall."
    )
    return header + "\n\n" + "\n".join(lines) + "\n"


def _simulator(spec: str, floorplans: Path, furnished: bool) -> Simulator:
    if spec == "floorplan":
        return FloorplanSimulator(floorplans, furnished)
    if spec in SIMULATORS:
        return SIMULATORS[spec]
    module, sep, name = spec.partition(":")
    if not sep:
        msg = f"--simulator {spec}: give {', '.join([*SIMULATORS, 'floorplan'])} or MODULE:FUNCTION"
        raise FloorplanError(msg)
    try:
        found: Simulator = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        msg = f"--simulator {spec}: {exc}"
        raise FloorplanError(msg) from None
    return found


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(
        prog="python -m lessmap.floorplan.bench",
        description="Room segmentation on floor plans: stream scores and the room-map "
        "benchmark (Bormann et al., ICRA 2016) for each method over simulated runs.",
    )
    parser.add_argument(
        "--simulator",
        default="building",
        help="building (generated buildings; maps: grid, corridor), floorplan (the benchmark's "
        "maps in --floorplans; sensors: laser270, laser360, sparse, camera) or MODULE:FUNCTION",
    )
    parser.add_argument(
        "--floorplans",
        type=Path,
        default=Path("..") / "shared" / "floorplans",
        help="folder of the benchmark's maps (default ../shared/floorplans)",
    )
    parser.add_argument("--furnished", action="store_true", help="floorplan: maps with furniture")
    parser.add_argument("--maps", nargs="+", default=["grid", "corridor"], help="map names")
    parser.add_argument("--sensors", nargs="+", default=["laser270"], help="sensor names")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--rates", nargs="+", type=float, default=[2.0], help="frames/s")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument("--tolerance-m", type=float, default=1.0)
    add_spans_in_views_option(parser)
    add_room_map_options(parser)
    parser.add_argument("--by", choices=GROUPS, default="map", help="rows per (default map)")
    parser.add_argument("--work", type=Path, help="keep the runs' files in this folder")
    parser.add_argument("--markdown", type=Path, help="also write the tables to this file")
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="no progress bar (drawn only on a terminal)"
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; print its tables (Markdown)."""
    from lessmap.cli.progress import progress
    from lessmap.errors import DatasetError

    args = build_parser().parse_args(argv)
    try:
        if args.jobs < 1 or args.tolerance_m <= 0:
            msg = "--jobs must be >= 1 and --tolerance-m > 0"
            raise FloorplanError(msg)
        try:
            params = room_map_params(args)
        except ValueError as exc:
            raise FloorplanError(str(exc)) from None
        simulator = _simulator(args.simulator, args.floorplans, args.furnished)
        cases = [
            BenchCase(map=m, sensor=s, seed=seed, rate_hz=rate)
            for m, s, seed, rate in product(args.maps, args.sensors, args.seeds, args.rates)
        ]
        with progress(args) as shown:
            results = run_bench(
                simulator,
                cases,
                methods=args.methods,
                params=params,
                tolerance_m=args.tolerance_m,
                jobs=args.jobs,
                work_dir=args.work,
                progress=shown,
                areas=AreaParams(spans_in_views=args.spans_in_views),
            )
    except (FloorplanError, DatasetError, OSError) as exc:
        sys.stderr.write(f"lessmap.floorplan.bench: {exc}\n")
        return 1
    text = markdown(results, args.tolerance_m, args.by)
    sys.stdout.write(text)
    if args.markdown is not None:
        args.markdown.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())

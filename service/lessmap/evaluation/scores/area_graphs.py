"""Area graphs against the truth: ``python -m lessmap.evaluation.scores.area_graphs``.

On simulated buildings (8 rooms, 3 robots; 270° and 360° sensors, dense and sparse wall
landmarks), seeds 0..N-1 (the ``min_containment`` sweep the default was chosen on) and
held-out seeds N..2N-1, it scores each robot area's room, each edge's adjacency (door pairs
found, over those crossed and over all), and the fleet merge's precision and recall of
"same fleet area" for "same room" per ``--containment``; then the fleet areas of mrclam6
without and with shared features. Definitions in full: ``docs/design/evaluation.md``.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap.core.areas.graph import AreaGraph, AreaGraphBuilder
from lessmap.core.areas.tracker import AreaParams, AreaTracker
from lessmap.evaluation.methods import dataset_area_params
from lessmap.evaluation.studies.areabench import SPARSE_SPACING_M, rows
from lessmap.files.frames import read_frames
from lessmap.sim.simulator import simulate
from lessmap_client.fleet_areas import MIN_CONTAINMENT, MIN_SHARED, FleetParams, fleet_graph

if TYPE_CHECKING:
    from collections.abc import Sequence

    from lessmap.files.frames import FrameRow
    from lessmap.sim.simulator import SimRun

SENSORS: dict[str, dict[str, Any]] = {
    "270°, dense": {"fov_deg": 270.0},
    "360°, dense": {"fov_deg": 360.0},
    "270°, sparse": {"fov_deg": 270.0, "landmark_spacing_m": SPARSE_SPACING_M},
    "360°, sparse": {"fov_deg": 360.0, "landmark_spacing_m": SPARSE_SPACING_M},
}
CONTAINMENTS = (0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 1.0)


@dataclass(slots=True)
class GraphTally:
    """Edges of robot graphs against the door graph, and fleet pairs per threshold."""

    edges: int = 0
    crossings: int = 0  # true room changes
    passages: int = 0  # passages counted on edges between adjacent rooms
    adjacent: int = 0
    same_room: int = 0
    crossed: int = 0  # door pairs (room pairs with a door) the robots crossed
    crossed_found: int = 0
    doors: int = 0  # door pairs of the building, once per robot
    doors_found: int = 0
    pairs_same_room: int = 0  # area pairs of different robots with one room
    # per min_containment: (pairs given one fleet area, of those in one room)
    fleet: dict[float, tuple[int, int]] | None = None

    def add_fleet(self, threshold: float, linked: int, correct: int) -> None:
        """Pool one run's fleet pairs at one threshold."""
        if self.fleet is None:
            self.fleet = {}
        old = self.fleet.get(threshold, (0, 0))
        self.fleet[threshold] = (old[0] + linked, old[1] + correct)


def robot_graphs(
    frames: Sequence[FrameRow], params: AreaParams | None = None
) -> tuple[dict[str, AreaGraph], dict[str, dict[int, int]]]:
    """Each robot's area graph and the area of each of its frames (seq -> area)."""
    trackers: dict[str, AreaTracker] = {}
    builders: dict[str, AreaGraphBuilder] = {}
    starts: dict[str, list[tuple[int, int]]] = {}  # robot -> (boundary_seq, raw area)
    seqs: dict[str, list[int]] = {}
    for frame in frames:
        tracker = trackers.setdefault(frame.robot, AreaTracker(params))
        builder = builders.setdefault(frame.robot, AreaGraphBuilder())
        seqs.setdefault(frame.robot, []).append(frame.seq)
        change = tracker.observe(frame.seq, frame.stamp_s, frame.features)
        if change is not None:
            builder.add(change)
            starts.setdefault(frame.robot, []).append((change.transition.boundary_seq, change.area))
    graphs = {robot: builders[robot].graph(tracker) for robot, tracker in trackers.items()}
    labels: dict[str, dict[int, int]] = {}
    for robot, tracker in trackers.items():
        marks = sorted(starts.get(robot, []))
        current, position, mine = 0, 0, {}
        for seq in sorted(seqs[robot]):
            while position < len(marks) and marks[position][0] <= seq:
                current = marks[position][1]
                position += 1
            mine[seq] = tracker.area_of(current)
        labels[robot] = mine
    return graphs, labels


def area_rooms(run: SimRun, labels: dict[str, dict[int, int]]) -> dict[tuple[str, int], int]:
    """Each robot area's room: the true room of most of its frames."""
    votes: dict[tuple[str, int], Counter[int]] = {}
    for row in run.truth:
        area = labels[row.robot][row.seq]
        votes.setdefault((row.robot, area), Counter())[row.room] += 1
    return {key: counts.most_common(1)[0][0] for key, counts in votes.items()}


def score_run(run: SimRun, tally: GraphTally, containments: Sequence[float]) -> None:
    """Add one simulated run's figures to the tally."""
    graphs, labels = robot_graphs(rows(run.frames))
    room = area_rooms(run, labels)
    doors = {frozenset(door.rooms) for door in run.building.doors}
    for robot, graph in graphs.items():
        crossed = {frozenset((c.from_room, c.to_room)) for c in run.changes_of(robot)}
        found: set[frozenset[int]] = set()
        for edge in graph.edges:
            pair = frozenset((room[robot, edge.a], room[robot, edge.b]))
            tally.edges += 1
            if len(pair) == 1:
                tally.same_room += 1
            elif pair in doors:
                tally.adjacent += 1
                tally.passages += edge.passages
                found.add(pair)
        tally.crossed += len(crossed)
        tally.crossings += len(run.changes_of(robot))
        tally.crossed_found += len(crossed & found)
        tally.doors += len(doors)
        tally.doors_found += len(doors & found)
    members = sorted(room)
    same = {
        (x, y) for x, y in itertools.combinations(members, 2) if x[0] != y[0] and room[x] == room[y]
    }
    tally.pairs_same_room += len(same)
    for threshold in containments:
        params = FleetParams(shared_features=True, min_containment=threshold)
        area_of = fleet_graph(graphs, params).area_of
        linked = {
            (x, y)
            for x, y in itertools.combinations(members, 2)
            if x[0] != y[0] and area_of[x] == area_of[y]
        }
        tally.add_fleet(threshold, len(linked), len(linked & same))


def _share(part: int, whole: int) -> str:
    return f"{part / whole:.0%} ({part}/{whole})" if whole else "-"


def run_seeds(seeds: range, containments: Sequence[float]) -> dict[str, GraphTally]:
    """Score every sensor on the buildings of ``seeds``."""
    tallies = {}
    for sensor, options in SENSORS.items():
        tally = tallies[sensor] = GraphTally()
        for seed in seeds:
            run = simulate(seed, rooms=8, robots=3, frames_per_robot=1000, **options)
            score_run(run, tally, containments)
    return tallies


def graph_table(tallies: dict[str, GraphTally], threshold: float) -> list[str]:
    """Robot graphs against the door graph, and the fleet merge at ``threshold``."""
    lines = [
        "| building | crossed adjacencies found | door-graph adjacencies found | edges not "
        "adjacent (same room / other) | passages / true room changes | fleet precision | "
        "fleet recall |",
        "|:---|---:|---:|---:|---:|---:|---:|",
    ]
    for sensor, t in tallies.items():
        linked, correct = (t.fleet or {}).get(threshold, (0, 0))
        wrong = t.edges - t.adjacent
        lines.append(
            f"| {sensor} | {_share(t.crossed_found, t.crossed)} | "
            f"{_share(t.doors_found, t.doors)} | {_share(wrong, t.edges)} "
            f"({t.same_room} / {wrong - t.same_room}) | {_share(t.passages, t.crossings)} | "
            f"{_share(correct, linked)} | {_share(correct, t.pairs_same_room)} |"
        )
    return lines


def sweep_table(tallies: dict[str, GraphTally]) -> list[str]:
    """Fleet precision / recall per ``min_containment`` (columns) and sensor (rows)."""
    thresholds = sorted({t for tally in tallies.values() for t in tally.fleet or {}})
    lines = [
        "| building | " + " | ".join(f"{t:g}" for t in thresholds) + " |",
        "|:---|" + "---:|" * len(thresholds),
    ]
    for sensor, tally in tallies.items():
        cells = []
        for t in thresholds:
            linked, correct = (tally.fleet or {}).get(t, (0, 0))
            precision = correct / linked if linked else 0.0
            recall = correct / tally.pairs_same_room if tally.pairs_same_room else 0.0
            cells.append(f"{precision:.0%} / {recall:.0%}")
        lines.append(f"| {sensor} | " + " | ".join(cells) + " |")
    return lines


def mrclam(path: Path, containments: Sequence[float]) -> str:
    """Fleet areas of a recorded file, without and with shared features."""
    graphs = robot_graphs(list(read_frames(path)), dataset_area_params(path))[0]
    robot_areas = ", ".join(f"{robot}: {len(g.nodes)}" for robot, g in sorted(graphs.items()))
    alone = len(fleet_graph(graphs, FleetParams()).nodes)
    shared = {
        t: len(fleet_graph(graphs, FleetParams(shared_features=True, min_containment=t)).nodes)
        for t in containments
    }
    listed = ", ".join(f"{t:g}: {n}" for t, n in shared.items())
    return (
        f"{path.name}: areas per robot {robot_areas}; fleet areas without shared features "
        f"{alone}; with shared features (min_shared {MIN_SHARED}), by min_containment: "
        f"{listed}"
    )


def report(seeds: int, datasets: Path | None, containments: Sequence[float]) -> str:
    """Markdown: the sweep on seeds 0..seeds-1, both seed sets at the default, the MRCLAM line."""
    chosen = run_seeds(range(seeds), containments)
    held_out = run_seeds(range(seeds, 2 * seeds), [MIN_CONTAINMENT])
    lines = [
        f"fleet merge, precision / recall by min_containment, seeds 0-{seeds - 1}:",
        "",
        *sweep_table(chosen),
        "",
        f"min_containment {MIN_CONTAINMENT:g}, seeds 0-{seeds - 1} (chosen on):",
        "",
        *graph_table(chosen, MIN_CONTAINMENT),
        "",
        f"min_containment {MIN_CONTAINMENT:g}, held-out seeds {seeds}-{2 * seeds - 1}:",
        "",
        *graph_table(held_out, MIN_CONTAINMENT),
        "",
    ]
    path = datasets / "mrclam6.frames.jsonl" if datasets is not None else None
    if path is not None and path.is_file():
        lines += [mrclam(path, containments), ""]
    elif path is not None:
        lines += [f"{path}: not present, skipped", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the figures."""
    parser = argparse.ArgumentParser(prog="python -m lessmap.evaluation.scores.area_graphs")
    parser.add_argument("--seeds", type=int, default=5, help="simulated runs per sensor and set")
    parser.add_argument(
        "--containment",
        type=float,
        nargs="+",
        default=list(CONTAINMENTS),
        help="min_containment values of the fleet sweep",
    )
    parser.add_argument(
        "--datasets",
        type=Path,
        default=Path("../shared/datasets"),
        help="folder of mrclam6.frames.jsonl (default ../shared/datasets)",
    )
    args = parser.parse_args(argv)
    sys.stdout.write(report(args.seeds, args.datasets, args.containment))
    return 0


if __name__ == "__main__":
    sys.exit(main())

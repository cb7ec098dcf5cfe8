"""Offline segmentation of a frames file: one independent partitioner per robot.

Also ``lessmap segment`` (``configure`` and ``run``, loaded by ``lessmap.cli.app`` on demand).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field, fields as dataclass_fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from lessmap.core import GraphError, Partitioner, Transition
from lessmap.core.areas.graph import AreaGraph, AreaGraphBuilder
from lessmap.core.areas.tracker import AreaTracker, AreaTransition
from lessmap.core.rooms.params import RoomParams
from lessmap.core.rooms.tracker import RoomTracker
from lessmap.errors import DatasetError
from lessmap_client.fleet_areas import MIN_CONTAINMENT, MIN_SHARED

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable, Iterable, Iterator

    from lessmap.core import PartitionParams
    from lessmap.core.areas.tracker import AreaParams
    from lessmap.files.frames import FrameRow

E = TypeVar("E", covariant=True)


@dataclass(slots=True)
class SegmentSummary:
    """Totals of an offline run."""

    frames: int = 0
    transitions: int = 0
    robots: dict[str, int] = field(default_factory=dict)  # robot -> transitions
    submaps: int = 0  # closed submaps plus one open submap per robot
    elapsed_s: float = 0.0
    areas: dict[str, int] | None = None  # robot -> areas opened (--method areas only)

    def as_dict(self) -> dict[str, Any]:
        """Return the summary as JSON-ready values."""
        per_frame_ms = 1000.0 * self.elapsed_s / self.frames if self.frames else 0.0
        record: dict[str, Any] = {
            "summary": True,
            "frames": self.frames,
            "robots": len(self.robots),
            "transitions": self.transitions,
            "transitions_per_robot": self.robots,
            "submaps": self.submaps,
            "elapsed_s": round(self.elapsed_s, 3),
            "ms_per_frame": round(per_frame_ms, 4),
        }
        if self.areas is not None:
            record["method"] = "areas"
            record["areas_per_robot"] = self.areas
        return record


def transition_record(robot: str, transition: Transition) -> dict[str, Any]:
    """Return one transition as a JSON-ready dict (the offline output line)."""
    return {
        "robot": robot,
        "seq": transition.seq,
        "boundary_seq": transition.boundary_seq,
        "stamp_s": transition.stamp_s,
        "reason": str(transition.reason),
        "ncut": transition.ncut,
        "lambda2": transition.lambda2,
        "closed": {
            "id": transition.closed.id,
            "first_seq": transition.closed.first_seq,
            "last_seq": transition.closed.last_seq,
            "frame_count": transition.closed.frame_count,
            "features": list(transition.closed.features),
        },
        "opened": {
            "id": transition.opened.id,
            "first_seq": transition.opened.first_seq,
            "features": list(transition.opened.features),
        },
        "boundary_features": list(transition.boundary_features),
    }


def area_record(robot: str, change: AreaTransition) -> dict[str, Any]:
    """Return one area change as a JSON-ready dict: the transition plus its areas."""
    return transition_record(robot, change.transition) | {
        "reason": str(change.reason),  # RECOGNISED has no value in the paper's Reason
        "area": change.area,
        "left_area": change.left_area,
        "revisit_of": change.revisit_of,
        "overlap": round(change.overlap, 4),
        "rule": str(change.rule),
    }


class _Observer(Protocol[E]):
    def observe(self, seq: int, stamp_s: float, features: Iterable[int]) -> E | None: ...


def _run(
    frames: Iterable[FrameRow],
    make: Callable[[], _Observer[E]],
    on_event: Callable[[str, E], None] | None,
    summary: SegmentSummary,
) -> dict[str, _Observer[E]]:
    """Feed each robot's frames to its own observer (made on its first frame); count events."""
    observers: dict[str, _Observer[E]] = {}
    started = time.perf_counter()
    for frame in frames:
        observer = observers.get(frame.robot)
        if observer is None:
            observer = observers[frame.robot] = make()
            summary.robots[frame.robot] = 0
        try:
            event = observer.observe(frame.seq, frame.stamp_s, frame.features)
        except GraphError as exc:
            msg = f"{frame.where or 'frame'}: robot {frame.robot}: {exc}"
            raise DatasetError(msg) from exc
        summary.frames += 1
        if event is not None:
            summary.transitions += 1
            summary.robots[frame.robot] += 1
            if on_event is not None:
                on_event(frame.robot, event)
    summary.elapsed_s = time.perf_counter() - started
    summary.submaps = summary.transitions + len(observers)
    return observers


def segment_areas(
    frames: Iterable[FrameRow],
    params: AreaParams,
    on_change: Callable[[str, AreaTransition], None] | None = None,
) -> SegmentSummary:
    """Run the area tracker of each robot over its frames (``--method areas``)."""
    return segment_area_graphs(frames, params, on_change)[0]


def segment_area_graphs(
    frames: Iterable[FrameRow],
    params: AreaParams | RoomParams,
    on_change: Callable[[str, AreaTransition], None] | None = None,
) -> tuple[SegmentSummary, dict[str, AreaGraph]]:
    """Run the area (or room) trackers as ``segment_areas`` does; also each robot's graph."""
    summary = SegmentSummary(areas={})
    builders: dict[str, AreaGraphBuilder] = {}

    def feed(robot: str, change: AreaTransition) -> None:
        builders.setdefault(robot, AreaGraphBuilder()).add(change)
        if on_change is not None:
            on_change(robot, change)

    make: Callable[[], AreaTracker | RoomTracker] = (
        (lambda: RoomTracker(params))
        if isinstance(params, RoomParams)
        else (lambda: AreaTracker(params))
    )
    trackers = _run(frames, make, feed, summary)
    graphs: dict[str, AreaGraph] = {}
    summary.areas = {}
    for robot, tracker in trackers.items():
        if isinstance(tracker, (AreaTracker, RoomTracker)):
            summary.areas[robot] = tracker.area_count
            graphs[robot] = builders.get(robot, AreaGraphBuilder()).graph(tracker)
    return summary, graphs


def segment(
    frames: Iterable[FrameRow],
    params: PartitionParams,
    on_transition: Callable[[str, Transition], None] | None = None,
) -> SegmentSummary:
    """Run the partitioner of each robot over its frames, deciding at every frame."""
    summary = SegmentSummary()
    _run(frames, lambda: Partitioner(params), on_transition, summary)
    return summary


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap segment``."""
    from lessmap.cli.flags import add_flags
    from lessmap.config.partitioning import add_method_option, add_partition_options
    from lessmap.config.settings import LimitSettings

    parser.description = (
        "Read FILE.frames.jsonl and print one JSON line per transition, then a summary line. "
        "Decides at every frame, exactly as the service does without load; a frame beyond the "
        "service's wire limits is an error, as it would be on the wire."
    )
    parser.add_argument("file", metavar="FILE", help="frames file (.frames.jsonl)")
    parser.add_argument("--robot", action="append", help="only this robot (repeatable)")
    parser.add_argument("--summary-only", action="store_true", help="print only the summary")
    add_method_option(parser)
    graph = parser.add_argument_group(
        "area graph (--method areas)",
        "Areas as nodes, passages as edges, per robot and for the fleet, written as one JSON "
        "object: {format: 'lessmap.area_graph/1', source, fleet_params, robots: {ROBOT: "
        "{nodes: [{area, frames, visits, first_seq, last_seq, features: [ids]}], edges: [{a, "
        "b, a_to_b, b_to_a, boundary_features: [[id, passages]]}]}}, fleet: {nodes: [{area, "
        "members: [[robot, area]], frames, visits, features: count}], edges: [{a, b, a_to_b, "
        "b_to_a, robots, boundary_features}]}}. Draw it with lessmap plot --area-graph.",
    )
    graph.add_argument(
        "--area-graph", type=Path, metavar="OUT.json", help="write the area graphs to OUT.json"
    )
    graph.add_argument(
        "--shared-features",
        action="store_true",
        # argparse formats help with %: the percent sign is written %%
        help="feature ids are global across the robots (fiducials, a shared landmark map): "
        f"areas of different robots that share at least {MIN_SHARED} features and "
        f"{MIN_CONTAINMENT * 100:.0f}%% of the smaller area's are one fleet area",
    )
    add_partition_options(parser)
    only = frozenset({"max_features_per_frame"})
    skip = frozenset(LimitSettings.model_fields) - only
    add_flags(parser, LimitSettings, title="limits (as lessmap serve's)", exclude=skip)


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap segment``: transitions as JSON lines, then the summary."""
    from pydantic import ValidationError
    from threadpoolctl import threadpool_limits

    from lessmap.cli.progress import line_count, progress, wanted
    from lessmap.config.partitioning import area_params, partition_settings
    from lessmap.config.settings import LimitSettings
    from lessmap.errors import ConfigError
    from lessmap.files.frames import read_frames, sparse_frames_warning
    from lessmap.progress import tracked

    if args.area_graph is not None and args.method == "paper":
        msg = "--area-graph needs --method areas or rooms (the paper names no areas)"
        raise ConfigError(msg)
    if args.shared_features and args.area_graph is None:
        msg = "--shared-features needs --area-graph OUT.json"
        raise ConfigError(msg)
    if args.area_graph is not None and not args.area_graph.resolve().parent.is_dir():
        # before the run, not after a long file was segmented for nothing
        msg = f"--area-graph {args.area_graph}: no folder {args.area_graph.parent}"
        raise ConfigError(msg)
    settings = partition_settings(args)
    params = settings.partition_params()
    given = vars(args).keys() & LimitSettings.model_fields.keys()
    values = {name: getattr(args, name) for name in given}  # the defaults are serve's
    try:
        limits = LimitSettings.model_validate(values).wire_limits()
    except ValidationError as exc:
        msg = f"invalid --max-features-per-frame: {exc.errors()[0]['msg']}"
        raise ConfigError(msg) from None
    path = Path(args.file)
    tally = [0, 0]  # frames, features: an empty run is an error, a sparse one a warning

    def counted(rows: Iterable[FrameRow]) -> Iterator[FrameRow]:
        for row in rows:
            tally[0] += 1
            tally[1] += len(row.features)
            yield row

    frames: Iterable[FrameRow] = read_frames(path, limits)
    if args.robot:
        robots = set(args.robot)
        frames = (f for f in frames if f.robot in robots)
    frames = counted(frames)

    # sys.stdout looked up at each write: on a terminal the bars redirect it above them.
    def emit(robot: str, transition: Transition) -> None:
        if not args.summary_only:
            sys.stdout.write(json.dumps(transition_record(robot, transition)) + "\n")

    def emit_area(robot: str, change: AreaTransition) -> None:
        if not args.summary_only:
            sys.stdout.write(json.dumps(area_record(robot, change)) + "\n")

    graphs: dict[str, AreaGraph] = {}
    # BLAS on one thread, as serve runs it: the same arithmetic as live, and no threads
    # fighting over a loaded host's cores for the small eigensolves of a camera robot.
    with threadpool_limits(limits=1), progress(args) as shown:
        shown.stage(f"segmenting {path.name}", line_count(path) if wanted(args) else None)
        frames = tracked(frames, shown)
        if args.method == "areas":
            areas = area_params(settings, empty_frames_omitted=args.empty_frames_omitted)
            summary, graphs = segment_area_graphs(frames, areas, on_change=emit_area)
            params = areas.proposal
        elif args.method == "rooms":
            rooms = RoomParams()
            summary, graphs = segment_area_graphs(frames, rooms, on_change=emit_area)
        else:
            summary = segment(frames, params, on_transition=emit)
    out = sys.stdout
    if tally[0] == 0:
        which = f" of robot {', '.join(sorted(args.robot))}" if args.robot else ""
        msg = f"{path}: no frames{which} to segment"
        raise DatasetError(msg)
    warning = sparse_frames_warning(str(path), tally[0], tally[1])
    if warning is not None:
        sys.stderr.write(f"lessmap segment: {warning}\n")
    record = summary.as_dict()
    record["file"] = path.name
    if args.area_graph is not None:
        record |= _write_graphs(args.area_graph, graphs, args.shared_features, path.name)
    record["params"] = {
        "ncut_min": params.ncut_min,
        "lambda2_min": params.lambda2_min,
        "seed_mode": str(params.seed_mode),
    }
    if args.method == "rooms":
        record["method"] = "rooms"
        record["params"] = {f.name: getattr(rooms, f.name) for f in dataclass_fields(rooms)}
    if args.method == "areas":
        # Every scalar of AreaParams (its proposer's are the paper's above), listed from the
        # dataclass so that a new rule's setting shows without a second list to keep.
        record["params"] |= {
            f.name: getattr(areas, f.name) for f in dataclass_fields(areas) if f.name != "proposal"
        }
    out.write(json.dumps(record) + "\n")
    out.flush()
    return 0


def _write_graphs(
    out: Path, graphs: dict[str, AreaGraph], shared_features: bool, source: str
) -> dict[str, Any]:
    """Write the robots' and the fleet's area graphs; return the summary's fields about them."""
    from lessmap.files.area_graph import graph_document, write_graph_file
    from lessmap_client.fleet_areas import FleetParams, fleet_graph

    params = FleetParams(shared_features=shared_features)
    fleet = fleet_graph(graphs, params)
    write_graph_file(out, graph_document(graphs, fleet, params, source))
    return {
        "area_graph": str(out),
        "fleet_areas": len(fleet.nodes),
        "fleet_passages": sum(edge.passages for edge in fleet.edges),
    }

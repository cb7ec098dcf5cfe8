"""Offline segmentation of a frames file: one independent partitioner per robot."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from lessmap.core import GraphError, Partitioner, Transition
from lessmap.errors import DatasetError

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from lessmap.core import PartitionParams
    from lessmap.frames_file import FrameRow


@dataclass(slots=True)
class SegmentSummary:
    """Totals of an offline run."""

    frames: int = 0
    transitions: int = 0
    robots: dict[str, int] = field(default_factory=dict)  # robot -> transitions
    submaps: int = 0  # closed submaps plus one open submap per robot
    elapsed_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """Return the summary as JSON-ready values."""
        per_frame_ms = 1000.0 * self.elapsed_s / self.frames if self.frames else 0.0
        return {
            "summary": True,
            "frames": self.frames,
            "robots": len(self.robots),
            "transitions": self.transitions,
            "transitions_per_robot": self.robots,
            "submaps": self.submaps,
            "elapsed_s": round(self.elapsed_s, 3),
            "ms_per_frame": round(per_frame_ms, 4),
        }


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


def segment(
    frames: Iterable[FrameRow],
    params: PartitionParams,
    on_transition: Callable[[str, Transition], None] | None = None,
) -> SegmentSummary:
    """Run the partitioner of each robot over its frames, deciding at every frame."""
    partitioners: dict[str, Partitioner] = {}
    summary = SegmentSummary()
    started = time.perf_counter()
    for frame in frames:
        partitioner = partitioners.get(frame.robot)
        if partitioner is None:
            partitioner = partitioners[frame.robot] = Partitioner(params)
            summary.robots[frame.robot] = 0
        try:
            transition = partitioner.observe(frame.seq, frame.stamp_s, frame.features)
        except GraphError as exc:
            msg = f"{frame.where or 'frame'} (robot {frame.robot}): {exc}"
            raise DatasetError(msg) from exc
        summary.frames += 1
        if transition is not None:
            summary.transitions += 1
            summary.robots[frame.robot] += 1
            if on_transition is not None:
                on_transition(frame.robot, transition)
    summary.elapsed_s = time.perf_counter() - started
    summary.submaps = summary.transitions + len(partitioners)
    return summary

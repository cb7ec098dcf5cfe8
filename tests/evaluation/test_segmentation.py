"""LESS-mapping runs as frame -> submap labels."""

from __future__ import annotations

import numpy as np

from lessmap.core import PartitionParams
from lessmap.evaluation.data.segmentation import consecutive, labels_from_transitions, run_lessmap
from lessmap.files.frames import FrameRow
from tests.evaluation.helpers import two_rooms


def rows(frames: list[list[int]]) -> list[FrameRow]:
    return [FrameRow("r", seq, float(seq), tuple(f), None) for seq, f in enumerate(frames)]


def test_consecutive_renumbers_in_order_of_first_appearance() -> None:
    assert consecutive([5, 5, 2, 2, 9, 2]).tolist() == [0, 0, 1, 1, 2, 1]
    assert consecutive([]).tolist() == []


def test_two_rooms_give_two_submaps_split_at_the_boundary() -> None:
    frames = two_rooms()[2]
    run = run_lessmap(rows(frames), PartitionParams.from_profile("laser"))
    assert len(run.transitions) == 1
    boundary = run.transitions[0].boundary_seq
    assert run.labels.tolist() == [0] * boundary + [1] * (len(frames) - boundary)
    room_a = {f for frame in frames[:boundary] for f in frame}
    assert room_a == set(range(1, 11))  # the boundary frame is the first one in room B
    assert all(e.seq < len(frames) for e in run.evaluations)
    seqs = [e.seq for e in run.evaluations]
    assert seqs == sorted(set(seqs))  # at most one evaluation per frame


def test_labels_follow_boundaries_with_gaps_in_seq() -> None:
    frames = two_rooms()[2]
    run = run_lessmap(rows(frames), PartitionParams.from_profile("laser"))
    seqs = np.arange(len(frames)) * 3  # the labels depend on seq, not on position
    shifted = labels_from_transitions(seqs, run.transitions)
    boundary = run.transitions[0].opened.first_seq
    assert shifted.tolist() == [0 if s < boundary else 1 for s in seqs]
    assert labels_from_transitions(seqs, []).tolist() == [0] * len(frames)

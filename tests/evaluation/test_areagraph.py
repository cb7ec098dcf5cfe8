"""The area-graph bench: robot areas scored as rooms, fleet pairs scored per threshold."""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.evaluation.scores.area_graphs import (
    GraphTally,
    area_rooms,
    graph_table,
    robot_graphs,
    score_run,
    sweep_table,
)
from lessmap.evaluation.studies.areabench import rows

if TYPE_CHECKING:
    from lessmap.sim.simulator import SimRun


def test_every_frame_has_an_area_and_every_area_a_room(sim_run: SimRun) -> None:
    graphs, labels = robot_graphs(rows(sim_run.frames))
    assert set(graphs) == {"robot0", "robot1"}
    for robot, graph in graphs.items():
        areas = {node.area for node in graph.nodes}
        assert set(labels[robot].values()) == areas
        assert sum(node.frames for node in graph.nodes) == len(labels[robot])
    rooms = area_rooms(sim_run, labels)
    assert set(rooms) == {(r, n.area) for r, g in graphs.items() for n in g.nodes}
    assert set(rooms.values()) <= {room.index for room in sim_run.building.rooms}


def test_a_lower_threshold_links_a_superset_of_pairs(sim_run: SimRun) -> None:
    tally = GraphTally()
    score_run(sim_run, tally, [0.05, 0.85, 1.0])
    assert tally.fleet is not None
    linked = {t: pair[0] for t, pair in tally.fleet.items()}
    correct = {t: pair[1] for t, pair in tally.fleet.items()}
    assert linked[0.05] >= linked[0.85] >= linked[1.0]
    assert correct[0.05] >= correct[0.85] >= correct[1.0]
    assert correct[0.05] == tally.pairs_same_room  # everything linked: recall 1
    assert tally.crossed_found <= tally.crossed
    assert tally.adjacent + tally.same_room <= tally.edges
    table = graph_table({"run": tally}, 0.85)
    assert len(table) == 3
    assert table[2].startswith("| run | ")
    assert len(sweep_table({"run": tally})) == 3

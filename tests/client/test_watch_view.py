"""The watch view's rows and lines name the area a robot is in, and a revisit."""

from __future__ import annotations

from lessmap_client.testing import make_state, make_transition
from lessmap_client.watch import FleetView


def test_a_revisit_is_named_in_the_line_and_the_row_follows_the_area() -> None:
    view = FleetView()
    first = make_transition("f", "r", closed_id=0)
    back = make_transition("f", "r", closed_id=1).model_copy(
        update={
            "reason": "RECOGNISED",
            "ncut": None,
            "lambda2": None,
            "area": 0,
            "left_area": 1,
            "revisit": True,
        }
    )
    assert view.add_transition(first).startswith("f/r: area 0 -> area 1 at frame")
    line = view.add_transition(back)
    assert line.startswith("f/r: area 1 -> area 0 again at frame")
    assert "RECOGNISED: its last frames fit an area it mapped before" in line
    assert "recognised" not in line.lower().replace("recognised:", "")  # said once, in words
    assert line.endswith("-> submap 2")
    coalesced = view.add_transition(back.model_copy(update={"batch_frames": 12}))
    assert coalesced.endswith("; decided over 12 coalesced frames")
    row = view.rows["f", "r"]
    assert (row.submap, row.area) == (2, 0)
    header, _rule, cells = view.table().splitlines()
    assert header.split()[:4] == ["robot", "session", "submap", "area"]
    assert cells.split()[2:4] == ["2", "0"]
    view.add_state(make_state("f", "r", frames_applied=40, transitions=3))
    assert (view.rows["f", "r"].submap, view.rows["f", "r"].area) == (3, 3)

"""Work budgets and admission of the SessionTable (sans-IO, real frames, a real store)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap.core import PartitionParams
from lessmap.core.areas.tracker import AreaParams
from lessmap.core.segmenter import SIGHTING_EDGES, Method
from lessmap.runtime.budget import EdgeLedger, SessionAdmission, pairs_of
from lessmap.runtime.sessions import (
    Identity,
    Segmenting,
    SessionLimits,
    SessionTable,
    SharedBudgets,
    commit_checkpoints,
)
from lessmap.runtime.sessions.model import DECISION_COST_PER_EDGE
from lessmap.runtime.store import CheckpointStore
from lessmap_schemas.errors import ErrorCode
from lessmap_schemas.messages import Frame

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

FLEET = "fleet"
LASER = PartitionParams.from_profile("laser")


def make_table(
    *,
    max_pairs: int = 0,
    max_edges: int = 0,
    ledger: EdgeLedger | None = None,
    admission: SessionAdmission | None = None,
    store: CheckpointStore | None = None,
    max_sessions: int = 8,
    max_batch_frames: int = 256,
    method: Method = Method.PAPER,
    area_params: AreaParams | None = None,
) -> SessionTable:
    # The paper by default: most tests here pin the CovGraph's own charge.
    return SessionTable(
        Segmenting(params=LASER, method=method, area_params=area_params or AreaParams()),
        SessionLimits(
            max_sessions=max_sessions,
            max_nodes=20_000,
            max_batch_frames=max_batch_frames,
            idle_timeout_s=600.0,
            max_pairs_per_frame=max_pairs,
            max_edges_per_session=max_edges,
        ),
        identity=Identity(instance="test"),
        store=store,
        budgets=SharedBudgets(ledger=ledger, admission=admission),
    )


def frame(seq: int, features: Sequence[int], session: str = "s1") -> Frame:
    return Frame(session=session, seq=seq, stamp_s=float(seq), features=list(features))


def test_a_frame_over_the_pair_budget_never_reaches_the_graph_and_is_counted() -> None:
    table = make_table(max_pairs=pairs_of(100))
    out = table.handle_batch([(FLEET, "r", frame(0, range(101)))], 0.0)
    assert [r.code for r in out.rejections] == [ErrorCode.LIMIT_EXCEEDED]
    assert "max_pairs_per_frame=4950" in out.rejections[0].detail
    out = table.handle_batch([(FLEET, "r", frame(1, range(100)))], 0.0)
    assert out.rejections == []
    state = table.state(FLEET, "r")
    assert state is not None
    assert (state.frames_applied, state.frames_rejected, state.frames_missing) == (1, 1, 0)
    assert state.edges == pairs_of(100)


def test_the_edge_budgets_refuse_what_could_cross_them_per_session_and_per_instance() -> None:
    table = make_table(max_edges=pairs_of(60))
    # One call, one decision at its end (no transition can shrink the graph in between):
    # 50 features make 1225 edges; 20 more could add 190 -> 1415 <= 1770, applied; 40 more
    # could add 780: over the budget, refused, the graph unchanged.
    run = [frame(0, range(50)), frame(1, range(50, 70)), frame(2, range(100, 140))]
    out = table.handle_batch([(FLEET, "r", f) for f in run], 0.0)
    assert [(r.code, r.seq) for r in out.rejections] == [(ErrorCode.GRAPH_LIMIT, 2)]
    assert "max_edges_per_session=1770" in out.rejections[0].detail
    state = table.state(FLEET, "r")
    assert state is not None
    assert state.edges <= pairs_of(60)
    assert (state.frames_applied, state.frames_rejected) == (2, 1)

    ledger = EdgeLedger(1, max_edges_total=1500)
    shared = make_table(ledger=ledger)
    assert shared.handle_batch([(FLEET, "a", frame(0, range(50)))], 0.0).rejections == []
    assert ledger.total() == pairs_of(50)
    out = shared.handle_batch([(FLEET, "b", frame(0, range(1000, 1030)))], 0.0)
    assert [r.code for r in out.rejections] == [ErrorCode.GRAPH_LIMIT]
    assert "max_edges_total=1500" in out.rejections[0].detail
    # A session that leaves memory gives its edges back.
    shared.close_all("shutdown")
    assert ledger.total() == 0


def test_a_dense_graph_above_400_nodes_charges_the_edge_budgets_its_matrix_bytes() -> None:
    # 420 features seen together: a complete graph, held as a matrix (the dense
    # store above dense_max_nodes); its cells cost more than its edges at 24 B an edge.
    ledger = EdgeLedger(1, max_edges_total=10**9)
    table = make_table(ledger=ledger)
    assert table.handle_batch([(FLEET, "dense", frame(0, range(420)))], 0.0).rejections == []
    state = table.state(FLEET, "dense")
    assert state is not None
    assert state.edges == pairs_of(420)  # the state reports true edges
    assert ledger.total() > pairs_of(420)  # the budgets see what the matrix holds
    # A sparse graph of as many edges is charged its edges.
    sparse_ledger = EdgeLedger(1, max_edges_total=10**9)
    sparse_table = make_table(ledger=sparse_ledger)
    walk = [frame(k, range(10 * k, 10 * k + 25)) for k in range(200)]
    for f in walk:
        assert sparse_table.handle_batch([(FLEET, "walk", f)], 0.0).rejections == []
    walked = sparse_table.state(FLEET, "walk")
    assert walked is not None
    assert sparse_ledger.total() == walked.edges


def test_new_sessions_are_rate_limited_per_fleet() -> None:
    table = make_table(admission=SessionAdmission(rate_per_s=1.0, burst=2), max_sessions=100)
    outs = [table.handle_batch([(FLEET, f"r{i}", frame(0, [1, 2]))], 0.0) for i in range(3)]
    assert [[r.code for r in o.rejections] for o in outs] == [[], [], [ErrorCode.SESSION_LIMIT]]
    assert "new sessions a second" in outs[2].rejections[0].detail
    # Another fleet has its own bucket; the first one refills with time.
    assert table.handle_batch([("other", "r0", frame(0, [1, 2]))], 0.0).rejections == []
    assert table.handle_batch([(FLEET, "r2", frame(1, [1, 2]))], 1.0).rejections[0].code == (
        ErrorCode.SEQ_GAP  # opened now; seq 0 was refused, so it is reported missing
    )


def test_a_full_shard_evicts_the_longest_idle_session_to_admit_a_new_one(tmp_path: Path) -> None:
    store = CheckpointStore(tmp_path)
    store.open()
    try:
        table = make_table(store=store, max_sessions=2)
        table.handle_batch([(FLEET, "old", frame(0, [1, 2]))], 4.8)
        table.handle_batch([(FLEET, "recent", frame(0, [3, 4]))], 5.0)
        # Both are busy (active less than a second ago): nothing can be evicted.
        busy = table.handle_batch([(FLEET, "new", frame(0, [5, 6]))], 5.5)
        assert [r.code for r in busy.rejections] == [ErrorCode.SESSION_LIMIT]
        assert "none idle" in busy.rejections[0].detail
        out = table.handle_batch([(FLEET, "new2", frame(0, [5, 6]))], 10.0)
        assert out.rejections == []
        assert out.evicted == 2  # both idle for 5 s or more, longest idle first
        assert len(table) == 1
        commit_checkpoints(out, store)  # the service's outbox, once the outcome is out
        # The evicted robot resumes where it stopped.
        back = table.handle_batch([(FLEET, "old", frame(1, [1, 2]))], 11.0)
        assert back.rejections == []
        assert [s.robot for s in back.resumed] == ["old"]
    finally:
        store.close()


def test_decide_every_lowers_the_coalescing_of_one_call_only() -> None:
    table = make_table(max_batch_frames=256)
    run = [(FLEET, "r", frame(s, [s, s + 1])) for s in range(10)]
    out = table.handle_batch(run[:5], 0.0, decide_every=1)
    assert [batch for _seconds, batch in out.decisions] == [1] * 5
    out = table.handle_batch(run[5:], 0.0)
    assert [batch for _seconds, batch in out.decisions] == [5]
    one = make_table(max_batch_frames=1)
    out = one.handle_batch(run, 0.0, decide_every=256)  # never above max_batch_frames
    assert [batch for _seconds, batch in out.decisions] == [1] * 10


def test_an_areas_session_is_charged_its_area_models_which_stay_bounded() -> None:
    # A robot that opens area after area of new features: its area models would grow
    # without end; rule 9 bounds them and the edge budgets see them.
    bound = 400
    ledger = EdgeLedger(1, max_edges_total=10**9)
    table = make_table(
        method=Method.AREAS, area_params=AreaParams(max_area_sightings=bound), ledger=ledger
    )
    charges = []
    for room in range(60):
        landmarks = range(1000 * room, 1000 * room + 20)
        run = [frame(room * 30 + k, landmarks) for k in range(30)]
        out = table.handle_batch([(FLEET, "r", f) for f in run], 0.0)
        assert out.rejections == []
        session = table._open[(FLEET, "r")]  # the segmenter behind the state
        tracker = session.segmenter.tracker  # type: ignore[attr-defined]
        assert tracker.sightings <= bound
        graph = tracker.proposer.graph.memory_edges
        assert ledger.total() == graph + SIGHTING_EDGES * tracker.sightings
        charges.append(ledger.total())
    state = table.state(FLEET, "r")
    assert state is not None
    assert state.transitions >= 50  # a new area per room
    assert max(charges[30:]) <= 2 * max(charges[:30])  # bounded, not growing with areas


def test_a_decisions_estimate_counts_the_pairs_the_sessions_sampling_keeps() -> None:
    # The heavy lane reads this estimate: a camera frame of 1,000 features costs an areas
    # session the pairs of the 256 it keeps, the paper's all 499,500.
    camera = range(1000)
    for method, kept in ((Method.AREAS, AreaParams().max_features_kept), (Method.PAPER, 1000)):
        table = make_table(method=method)
        key = (FLEET, "cam")
        new = table.decision_cost(key, len(camera))  # before its session opens
        assert table.handle_batch([(FLEET, "cam", frame(0, range(20)))], 0.0).rejections == []
        opened = table.decision_cost(key, len(camera)) - table.decision_cost(key)
        assert new - table.decision_cost((FLEET, "unknown")) == opened
        assert opened == DECISION_COST_PER_EDGE * pairs_of(kept), method

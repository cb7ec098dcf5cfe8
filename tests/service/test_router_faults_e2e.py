"""The router dies, or one instance is cut off from it: real processes on loopback.

(a) Two ``lessmap serve -m client`` instances and ``lessmap replay`` of mrclam6 (speed 20)
through one ``lessmap router``; the router is killed -9 mid-replay and restarted on the same
port.
(b) Two linked routers, A and B: the robots, the recorder and instance ``inst-a`` on A,
``inst-b`` on B; router B is killed -9 mid-replay (``inst-b`` is cut off, the robots still
reach ``inst-a``) and restarted later; (c) the same, cut longer than the robots' caches.

Judged as the fault tests of round one (``test_failover_e2e.py``): every robot's frames
applied (the replay exits 0), per (robot, seq) exactly the offline transition on the bus
(the recorder's live copies plus what the instances' transition caches still hold), and no
identity (fleet, robot, session, submap id) published with two contents.
"""

from __future__ import annotations

import signal
import time
from typing import TYPE_CHECKING, Any

import pytest
import zenoh
from zenoh import ext

from lessmap.files.frames import read_frames
from lessmap_client.session import open_session
from lessmap_schemas import keys
from lessmap_schemas.codec import decode
from lessmap_schemas.messages import Transition
from tests.conftest import dataset, free_port, wait_until
from tests.service.test_failover_e2e import (
    FLEET,
    BusRecorder,
    Proc,
    Site,
    compare,
    covered,
    failure_context,
    replay_summary,
    start_replay,
)
from tests.service.test_serve_e2e import as_record, offline_transitions

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

pytestmark = [pytest.mark.timeout(600), pytest.mark.slow]

CACHE = 1000  # transitions kept per robot: every one of the run stays fetchable


def instance(site: Site, name: str, endpoint: str) -> Proc:
    """An instance as ``Site.instance`` starts one, on ``endpoint``, caching every transition."""
    return site.start(
        name,
        "serve",
        "-m",
        "client",
        "-e",
        endpoint,
        "--instance",
        name,
        "--state-dir",
        str(site.tmp_path / f"state-{name}"),
        "--max-batch-frames",
        "1",
        "--method",
        "paper",
        "--catchup-wait-s",
        "10",
        "--transition-cache",
        str(CACHE),
        "--cfg",
        "scouting/multicast/enabled:false",
    )


def router(site: Site, name: str, listen: str, *connect: str) -> Proc:
    argv = ["router", "-l", listen]
    for endpoint in connect:
        argv += ["-e", endpoint]
    proc = site.start(name, *argv, log_name=f"{name}-{time.monotonic_ns()}")
    wait_until(lambda: "listening" in proc.log(), 30.0, f"router {name}")
    return proc


def kill_9(proc: Proc) -> None:
    proc.process.send_signal(signal.SIGKILL)
    proc.process.wait(10)


@pytest.fixture
def bare_site(tmp_path: Path) -> Iterator[Site]:
    """A site without a router yet; every process is stopped by its PID at teardown."""
    s = Site(f"tcp/127.0.0.1:{free_port()}", tmp_path, [])
    yield s
    for proc in reversed(s.procs):
        proc.stop()


def cached_transitions(
    session: zenoh.Session,
    complete: Callable[[list[Transition]], bool],
    wait_s: float = 3.0,
    max_wait_s: float = 30.0,
) -> list[Transition]:
    """What the instances' transition caches hold now (a late joiner's history).

    One history query to the publishers there are (all of them, the run being over):
    with late-publisher detection as well, a detection's query raced the first one, and
    the subscriber, having delivered a publisher's newest transitions, dropped the older
    ones of the other reply as stale (seen on a loaded machine: 6 of a robot's 116).
    Listens ``wait_s``, then on until ``complete`` holds or ``max_wait_s``: a reply that
    never comes still fails the comparison after the bound.
    """
    got: list[Transition] = []
    subscriber = ext.declare_advanced_subscriber(
        session,
        keys.transitions(FLEET),
        lambda sample: got.append(decode(sample.payload.to_bytes(), Transition)),
        history=ext.HistoryConfig(detect_late_publishers=False, max_samples=CACHE),
    )
    time.sleep(wait_s)
    deadline = time.monotonic() + max_wait_s - wait_s
    while not complete(list(got)) and time.monotonic() < deadline:
        time.sleep(0.2)
    subscriber.undeclare()
    return list(got)


def identity_conflicts(transitions: list[Transition]) -> list[str]:
    """Identities (fleet, robot, session, closed submap id) published with two contents."""
    seen: dict[tuple[str, str, str, int], list[dict[str, Any]]] = {}
    for t in transitions:
        copies = seen.setdefault((t.fleet, t.robot, t.session, t.closed.id), [])
        record = as_record(t)
        if record not in copies:
            copies.append(record)
    return [f"{key}: {len(copies)} contents" for key, copies in seen.items() if len(copies) > 1]


def judge(
    site: Site, replay: Proc, bus: BusRecorder, session: zenoh.Session, expected: Any
) -> list[Transition]:
    """The replay's verdict and the bus against the offline run; returns what was seen."""
    code = replay.process.wait(300)
    summary = replay_summary(replay)
    assert code == 0, failure_context(summary, site)
    for robot, counts in summary["per_robot"].items():
        assert counts["applied"] == counts["offered"], (robot, counts)
    time.sleep(1.0)  # the last transitions on their way
    live = [t for _, t in bus.got]
    seen = live + cached_transitions(session, lambda cached: compare(expected, live + cached) == [])
    assert compare(expected, seen) == []
    assert identity_conflicts(seen) == []
    return seen


def test_router_killed_mid_replay_and_restarted_loses_nothing(bare_site: Site) -> None:
    site = bare_site
    path = dataset("mrclam6.frames.jsonl")
    expected = offline_transitions(list(read_frames(path)))
    total = sum(len(v) for v in expected.values())
    first = router(site, "router", site.endpoint)
    names = {"inst-a", "inst-b"}
    for name in sorted(names):
        instance(site, name, site.endpoint)
    session = open_session([site.endpoint], timeout_s=20.0)
    try:
        bus = BusRecorder(session)
        wait_until(lambda: covered(session, names), 60.0, "two instances to share out")
        # Speed 20: ~50 frames/s a robot, so a cache of 1,000 frames holds 20 s: the outage,
        # the router's restart and both instances' rejoin (they dropped their partitions).
        replay = start_replay(site, path, "20")
        wait_until(lambda: len(bus.got) >= total // 3, 120.0, "a third of the transitions")
        kill_9(first)
        time.sleep(2.0)  # the robots go on; their caches hold the outage
        router(site, "router", site.endpoint)
        wait_until(lambda: covered(session, names), 60.0, "the instances back on the router")
        judge(site, replay, bus, session, expected)
    finally:
        session.close()


def test_an_instance_cut_off_from_the_robots_is_replaced_and_publishes_nothing_stale(
    bare_site: Site,
) -> None:
    site = bare_site
    path = dataset("mrclam6.frames.jsonl")
    expected = offline_transitions(list(read_frames(path)))
    total = sum(len(v) for v in expected.values())
    a_endpoint, b_endpoint = site.endpoint, f"tcp/127.0.0.1:{free_port()}"
    router(site, "router-a", a_endpoint)
    b = router(site, "router-b", b_endpoint, a_endpoint)
    instances = {
        "inst-a": instance(site, "inst-a", a_endpoint),
        "inst-b": instance(site, "inst-b", b_endpoint),
    }
    session = open_session([a_endpoint], timeout_s=20.0)
    try:
        bus = BusRecorder(session)
        wait_until(lambda: covered(session, set(instances)), 60.0, "two instances to share out")
        replay = start_replay(site, path, "40")
        wait_until(lambda: len(bus.got) >= total // 3, 120.0, "a third of the transitions")
        kill_9(b)  # inst-b keeps running, alone; the robots reach only inst-a
        cut_at = time.monotonic()
        wait_until(lambda: covered(session, {"inst-a"}), 30.0, "inst-a to take every partition")
        time.sleep(3.0)  # the cut lasts while the robots go on
        router(site, "router-b", b_endpoint, a_endpoint)
        healed_at = time.monotonic()
        wait_until(lambda: covered(session, set(instances)), 60.0, "the two to share out again")
        seen = judge(site, replay, bus, session, expected)
        # While cut off, inst-b reached nobody: nothing it published then is on the bus.
        cut_off = [
            at for at, t in bus.got if t.instance == "inst-b" and cut_at + 0.5 < at < healed_at
        ]
        assert cut_off == []
        assert {t.instance for t in seen} == set(instances)
        assert "session resumed from the state store" in instances["inst-a"].log()
    finally:
        session.close()


def test_a_cut_longer_than_the_robots_caches_loses_nothing(bare_site: Site) -> None:
    site = bare_site
    path = dataset("mrclam6.frames.jsonl")
    expected = offline_transitions(list(read_frames(path)))
    total = sum(len(v) for v in expected.values())
    a_endpoint, b_endpoint = site.endpoint, f"tcp/127.0.0.1:{free_port()}"
    router(site, "router-a", a_endpoint)
    b = router(site, "router-b", b_endpoint, a_endpoint)
    names = {"inst-a", "inst-b"}
    instance(site, "inst-a", a_endpoint)
    instance(site, "inst-b", b_endpoint)
    session = open_session([a_endpoint], timeout_s=20.0)
    try:
        bus = BusRecorder(session)
        wait_until(lambda: covered(session, names), 60.0, "two instances to share out")
        replay = start_replay(site, path, "40")
        wait_until(lambda: len(bus.got) >= total // 4, 120.0, "a quarter of the transitions")
        kill_9(b)
        # At speed 40 a robot of mrclam6 puts ~90-100 frames/s: 13 s outrun its cache of
        # 1,000 frames, while inst-a, which took the partitions over, applies every frame.
        time.sleep(13.0)
        router(site, "router-b", b_endpoint, a_endpoint)
        wait_until(lambda: covered(session, names), 60.0, "the two to share out again")
        judge(site, replay, bus, session, expected)
    finally:
        session.close()

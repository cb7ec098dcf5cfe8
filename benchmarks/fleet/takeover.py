"""Take-over after ``kill -9``: how long until every robot of the killed instance is served again.

``run_load`` with ``LoadSpec.kill_after_s`` kills one instance (SIGKILL, by PID) at
``t0 + kill_after_s``. The robots whose partition the victim owned (rendezvous over the
instances' names, contract section 2a) are the *moved* robots. For each one the watch here
polls the fleet's ``SessionState`` (one wildcard query, every reply timestamped on receipt)
and records the first moment a survivor answers for it with ``last_seq`` past the last frame
the robot had published when the kill happened (from the generators' schedule): the new
owner has resumed the session from the shipped checkpoint, caught up from the robot's cache
and applied (and decided on) a frame sent after the kill. Beside it, the moment the
survivors' ``lessmap_partitions_owned`` sum is back to ``PARTITIONS`` and the take-over times the
survivors log ("took N partition(s) in X ms").

Resolution: the poll period (``poll_s``) plus one query round trip. The polling itself costs
the survivors one ``SessionState`` per robot they hold per poll, on the same two cores.
"""

from __future__ import annotations

import math
import re
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from benchmarks.fleet.loadgen import robot_name
from benchmarks.fleet.metrics import parse_metrics
from benchmarks.fleet.process import proc_cpu_s
from benchmarks.fleet.report import InstanceFigures

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    import zenoh

    from benchmarks.fleet.loadgen import LoadSpec
    from benchmarks.fleet.process import ServiceProcess, WorkerView

_TOOK = re.compile(r"took (\d+) partition\(s\) in (\d+) ms \((\d+) checkpoint")


@dataclass(slots=True, kw_only=True)
class TakeoverResult:
    """What the watch measured after one kill."""

    victim: str
    killed_at: float  # Unix seconds
    moved_robots: int
    partitions_moved: int
    poll_s: float
    served_after_s: dict[str, float] = field(default_factory=dict)  # robot -> s after the kill
    unresolved: list[str] = field(default_factory=list)
    partitions_back_s: float = math.nan  # survivors own every partition again
    took_ms: list[tuple[int, int, int]] = field(default_factory=list)  # (partitions, ms, ckpts)
    polls: int = 0

    def quantile(self, q: float) -> float:
        """Quantile of the per-robot times (nan when none was measured)."""
        times = sorted(self.served_after_s.values())
        if not times:
            return math.nan
        return times[min(len(times) - 1, int(q * len(times)))]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        times = sorted(self.served_after_s.values())
        return {
            "victim": self.victim,
            "moved_robots": self.moved_robots,
            "partitions_moved": self.partitions_moved,
            "served_again_s": {
                "p50": self.quantile(0.5),
                "p90": self.quantile(0.9),
                "max": times[-1] if times else math.nan,
                "min": times[0] if times else math.nan,
                "n": len(times),
            },
            "unresolved": self.unresolved,
            "partitions_back_s": self.partitions_back_s,
            "took_ms": self.took_ms,
            "poll_s": self.poll_s,
            "polls": self.polls,
        }


class TakeoverWatch:
    """Polls the fleet's states on a thread after a kill (bounded by ``timeout_s``)."""

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        moved: dict[str, int],
        victim: ServiceProcess | WorkerView,
        survivors: Sequence[ServiceProcess | WorkerView],
        killed_at: float,
        partitions_moved: int,
        *,
        poll_s: float = 0.1,
        timeout_s: float = 60.0,
    ) -> None:
        """``moved``: robot -> the last seq it had published when the kill happened."""
        self._session = session
        self._fleet = fleet
        self._pending = dict(moved)
        self._survivors = survivors
        self._timeout_s = timeout_s
        self.result = TakeoverResult(
            victim=victim.instance,
            killed_at=killed_at,
            moved_robots=len(moved),
            partitions_moved=partitions_moved,
            poll_s=poll_s,
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-takeover", daemon=True)

    def start(self) -> None:
        """Start polling."""
        self._thread.start()

    def _run(self) -> None:
        import zenoh

        from lessmap_schemas import keys
        from lessmap_schemas.codec import decode
        from lessmap_schemas.errors import WireError
        from lessmap_schemas.messages import SessionState
        from lessmap_schemas.partition import PARTITIONS

        r = self.result
        deadline = time.time() + self._timeout_s
        victim = r.victim
        while (self._pending or math.isnan(r.partitions_back_s)) and time.time() < deadline:
            if self._stop.is_set():
                break
            started = time.time()
            if math.isnan(r.partitions_back_s) and self._owned_by_survivors() >= PARTITIONS:
                r.partitions_back_s = time.time() - r.killed_at
            if self._pending:
                r.polls += 1
                replies = self._session.get(
                    keys.state(self._fleet, "*"),
                    target=zenoh.QueryTarget.ALL,
                    consolidation=zenoh.ConsolidationMode.NONE,
                    timeout=2.0,
                )
                for reply in replies:
                    at = time.time()
                    if reply.ok is None:
                        continue
                    try:
                        state = decode(reply.ok.payload.to_bytes(), SessionState)
                    except WireError:
                        continue
                    threshold = self._pending.get(state.robot)
                    if (
                        threshold is not None
                        and state.instance != victim
                        and state.last_seq is not None
                        and state.last_seq > threshold
                    ):
                        r.served_after_s[state.robot] = at - r.killed_at
                        del self._pending[state.robot]
            time.sleep(max(0.0, self.result.poll_s - (time.time() - started)))

    def _owned_by_survivors(self) -> float:
        total = 0.0
        for instance in self._survivors:
            try:
                total += parse_metrics(instance.metrics_text()).get("lessmap_partitions_owned", 0.0)
            except OSError:
                return 0.0
        return total

    def finish(self, timeout_s: float = 70.0) -> TakeoverResult:
        """Wait for the watch to end (all robots served, or its deadline); read the logs."""
        self._thread.join(timeout_s)
        self._stop.set()
        self._thread.join(5.0)
        self.result.unresolved = sorted(self._pending)
        for instance in self._survivors:
            text = instance.log_path.read_text(encoding="utf-8", errors="replace")
            for line in text.splitlines():
                match = _TOOK.search(line)
                # Only the take-overs after the kill (each survivor's start logs one too).
                if match and "partition(s) in" in line and self._after_kill(line):
                    self.result.took_ms.append((int(match[1]), int(match[2]), int(match[3])))
        return self.result

    def _after_kill(self, line: str) -> bool:
        """Whether a log line is dated after the kill (lines start with a local timestamp)."""
        stamp = re.match(r"(\d{4}-\d\d-\d\d[ T]\d\d:\d\d:\d\d)[.,](\d+)", line)
        if stamp is None:
            return True
        when = time.mktime(time.strptime(stamp[1].replace("T", " "), "%Y-%m-%d %H:%M:%S"))
        return when + float(f"0.{stamp[2]}") >= self.result.killed_at - 0.001


def _kill_one(
    spec: LoadSpec,
    services: Sequence[ServiceProcess | WorkerView],
    t0: float,
    cpu_start: dict[int, float],
    figures: dict[str, InstanceFigures],
    session: zenoh.Session,
    say: Callable[[str], None],
) -> TakeoverWatch:
    """At ``t0 + kill_after_s``, kill -9 the first instance; watch its robots move."""
    from lessmap_schemas.partition import assignment, partition_of

    assert spec.kill_after_s is not None
    victim, survivors = services[0], services[1:]
    owners = assignment([i.instance for i in services])
    lost = {p for p, (owner, _) in owners.items() if owner == victim.instance}
    period = 1.0 / spec.rate_hz
    time.sleep(max(0.0, t0 + spec.kill_after_s - time.time()))
    metrics = parse_metrics(victim.metrics_text())
    cpu = proc_cpu_s(victim.pid) - cpu_start[victim.pid]
    killed_at = victim.kill9()
    figures[victim.instance] = InstanceFigures.from_metrics(
        metrics,
        name=victim.instance,
        pid=victim.pid,
        robots=0,
        partitions_at_start=len(lost),
        frames_offered=0,
        cpu_load_s=cpu,
        killed=True,
    )
    # The last frame each moved robot had published at the kill, from the schedule
    # (robot i publishes frame k at t0 + k/R + i/(N R)).
    moved: dict[str, int] = {}
    for index in range(spec.robots):
        name = robot_name(index)
        if partition_of(spec.fleet, name) in lost:
            due = (killed_at - t0 - index * period / spec.robots) / period
            moved[name] = min(spec.frames_per_robot - 1, math.floor(due))
    say(
        f"killed {victim.instance} (pid {victim.pid}) with SIGKILL: {len(moved)} robots on "
        f"{len(lost)} partitions move"
    )
    watch = TakeoverWatch(
        session,
        spec.fleet,
        moved,
        victim,
        survivors,
        killed_at,
        len(lost),
        timeout_s=max(10.0, spec.duration_s - spec.kill_after_s + 10.0),
    )
    watch.start()
    return watch

"""The report of the fleet load benchmark: Prometheus histograms, figures, text and JSON.

``LoadReport`` holds everything one load run measured; ``format_report`` and ``knee_row``
print it, ``_json`` writes it as strict JSON. ``parse_metrics`` and ``histogram``
(``metrics.py``) read the service's Prometheus exposition; ``summarize_profile``
(``profile_summary.py``) condenses py-spy collapsed stacks.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any

from benchmarks.fleet.loadgen import LoadSpec
from benchmarks.fleet.metrics import Histogram
from lessmap.core.segmenter import DEFAULT_METHOD

_QUEUE_P99_TARGET_S = 0.25
_RSS_FLAT_FRACTION = 0.05  # growth over the load's second half above this share: not flat


# -- the report --------------------------------------------------------------------------------


@dataclass(slots=True, kw_only=True)
class InstanceFigures:
    """One service instance of a run: what its robots offered and what its metrics counted.

    ``robots`` are the robots whose partition the instance owned when the load started
    (rendezvous over the instances' names); each sends its frames and one ``SessionEnd`` on
    its frames key, both counted by ``lessmap_frames_received_total``. A killed instance's
    figures are its last scrape, just before the kill.
    """

    name: str
    pid: int
    robots: int
    partitions_at_start: int
    frames_offered: int  # frames its robots published (the whole run)
    received: float  # lessmap_frames_received_total (frames and SessionEnds)
    foreign: float  # lessmap_frames_foreign_total
    applied: float  # lessmap_frames_applied_total
    recovered: float  # lessmap_frames_recovered_total (from the robots' caches)
    partitions_owned: float  # lessmap_partitions_owned at the end
    moves_in: float
    moves_out: float
    checkpoints_shipped: float
    checkpoints_received: float
    cpu_load_s: float  # CPU while the generators published (until the kill, if killed)
    killed: bool = False

    @property
    def us_per_received(self) -> float:
        """CPU per received sample during the load, microseconds."""
        return 1e6 * self.cpu_load_s / self.received if self.received else math.nan

    @classmethod
    def from_metrics(cls, metrics: dict[str, float], **fields: Any) -> InstanceFigures:
        """Fill the metric fields from one instance's ``parse_metrics``."""
        return cls(
            received=metrics.get("lessmap_frames_received_total", 0.0),
            foreign=metrics.get("lessmap_frames_foreign_total", 0.0),
            applied=metrics.get("lessmap_frames_applied_total", 0.0),
            recovered=metrics.get("lessmap_frames_recovered_total", 0.0),
            partitions_owned=metrics.get("lessmap_partitions_owned", 0.0),
            moves_in=metrics.get('lessmap_partition_moves_total{direction="in"}', 0.0),
            moves_out=metrics.get('lessmap_partition_moves_total{direction="out"}', 0.0),
            checkpoints_shipped=metrics.get("lessmap_checkpoints_shipped_total", 0.0),
            checkpoints_received=metrics.get("lessmap_checkpoints_received_total", 0.0),
            **fields,
        )


@dataclass(slots=True, kw_only=True)
class LoadReport:
    """Everything one load run measured (``as_dict`` for JSON)."""

    spec: LoadSpec
    landmark_spacing_m: float
    features_mean: float
    load_before: tuple[float, float, float]
    load_after: tuple[float, float, float]
    cpus: int
    offered: int
    applied: int
    missing: int
    duplicate: int
    rejected: int
    sessions_reported: int
    drained: bool
    drain_s: float
    lateness_max_s: float
    late_frames: int
    generator_cpu_s: float
    decisions: float
    coalesced_batches: float
    transitions_service: int
    transitions_received: int
    robots_with_transitions: list[str]
    queue_latency: Histogram
    frame_latency: Histogram  # empty (count 0) when the service does not export it
    decision_seconds: Histogram
    e2e_s: list[float]  # publish -> transition received, sorted
    service_cpu_s: float
    service_cpu_load_s: float  # CPU while the generators published
    service_threads_cpu_s: dict[str, float]  # since start, by thread name
    rss_samples: list[tuple[float, int, float]]
    rss_hwm_kib: int
    baseline_observe_us: float
    baseline_apply_us: float
    baseline_coalesced_us: float
    baseline_frames: int
    baseline_robots: int = 0
    applied_by_robot: dict[str, int] = field(default_factory=dict)
    offered_by_robot: dict[str, int] = field(default_factory=dict)
    transitions_by_robot: dict[str, list[int]] = field(default_factory=dict)
    instance_figures: list[InstanceFigures] = field(default_factory=list)
    checkpoint_puts: int = 0  # checkpoints seen on lessmap/v4/@/checkpoints/** (N > 1)
    checkpoint_bytes: int = 0  # their payload bytes
    checkpoint_zlib_ratio: float = math.nan  # zlib level 1 size / raw, every tenth one
    takeover: dict[str, Any] | None = None  # TakeoverResult.as_dict() of a kill run
    router_cpu_load_s: float = math.nan  # the `lessmap router` (N > 1) while generators ran
    router_bytes_in: int = 0  # bytes the router received during the load (ss), N > 1
    router_bytes_out: int = 0  # bytes it sent
    notes: list[str] = field(default_factory=list)

    @property
    def lost(self) -> int:
        """Frames offered but never applied."""
        return self.offered - self.applied

    @property
    def frames_per_decision(self) -> float:
        """Mean frames a spectral decision covered (coalescing)."""
        return self.applied / self.decisions if self.decisions else math.nan

    @property
    def service_us_per_frame(self) -> float:
        """Service CPU per applied frame, microseconds."""
        return 1e6 * self.service_cpu_s / self.applied if self.applied else math.nan

    def rss_growth(self) -> tuple[float, float, float]:
        """(RSS at the end of warm-up, at the end of the load, relative growth), MiB."""
        load_end = self.spec.duration_s
        window = [s for s in self.rss_samples if self.spec.warmup_s <= s[0] <= load_end]
        if len(window) < 2:
            return math.nan, math.nan, math.nan
        first = sum(s[1] for s in window[:3]) / len(window[:3]) / 1024
        last = sum(s[1] for s in window[-3:]) / len(window[-3:]) / 1024
        return first, last, (last - first) / first

    @property
    def rss_flat(self) -> bool:
        """RSS grew by at most 5 % over the second half of the load."""
        growth = self.rss_growth()[2]
        return not math.isnan(growth) and growth <= _RSS_FLAT_FRACTION

    def e2e(self, q: float) -> float:
        """Quantile of publish -> transition received, seconds."""
        if not self.e2e_s:
            return math.nan
        return self.e2e_s[min(len(self.e2e_s) - 1, int(q * len(self.e2e_s)))]

    @property
    def service_latency(self) -> tuple[str, Histogram]:
        """The service-side latency the bar is judged on, and its name.

        ``lessmap_frame_latency_seconds`` (receipt to the end of the covering decision) when
        the service exports it; otherwise ``lessmap_queue_latency_seconds`` (receipt to the
        start of the worker round), which leaves the round itself out.
        """
        if self.frame_latency.count > 0:
            return "receipt->decision", self.frame_latency
        return "queue wait", self.queue_latency

    def passes(self) -> bool:
        """The issue's bar: 0 lost, p99 service latency <= 250 ms, RSS flat.

        A run that killed an instance is not judged on RSS (a third or more of it went).
        """
        return (
            self.drained
            and self.lost == 0
            and self.service_latency[1].quantile(0.99) <= _QUEUE_P99_TARGET_S
            and (self.rss_flat or self.takeover is not None)
        )

    def meets_latency_bar(self) -> bool:
        """Every frame applied and p99 receipt -> decision <= 250 ms (RSS not judged)."""
        return (
            self.drained
            and self.lost == 0
            and self.service_latency[1].quantile(0.99) <= _QUEUE_P99_TARGET_S
        )

    def as_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (seconds, KiB)."""
        rss = self.rss_growth()
        return {
            "spec": asdict(self.spec),
            "landmark_spacing_m": self.landmark_spacing_m,
            "features_mean": self.features_mean,
            "load_average": {"before": self.load_before, "after": self.load_after},
            "cpus": self.cpus,
            "frames": {
                "offered": self.offered,
                "applied": self.applied,
                "lost": self.lost,
                "missing": self.missing,
                "duplicate": self.duplicate,
                "rejected": self.rejected,
            },
            "sessions_reported": self.sessions_reported,
            "drained": self.drained,
            "drain_s": self.drain_s,
            "generator": {
                "lateness_max_s": self.lateness_max_s,
                "late_frames": self.late_frames,
                "cpu_s": self.generator_cpu_s,
            },
            "decisions": self.decisions,
            "coalesced_batches": self.coalesced_batches,
            "frames_per_decision": self.frames_per_decision,
            "transitions": {
                "service": self.transitions_service,
                "received": self.transitions_received,
                "robots": len(self.robots_with_transitions),
            },
            "queue_latency_s": _histogram_dict(self.queue_latency),
            "frame_latency_s": _histogram_dict(self.frame_latency),
            "decision_s": _histogram_dict(self.decision_seconds),
            "publish_to_transition_s": {
                "p50": self.e2e(0.5),
                "p99": self.e2e(0.99),
                "max": self.e2e_s[-1] if self.e2e_s else math.nan,
                "n": len(self.e2e_s),
            },
            "service": {
                "cpu_s": self.service_cpu_s,
                "cpu_during_load_s": self.service_cpu_load_s,
                "cpu_by_thread_s": self.service_threads_cpu_s,
                "us_per_frame": self.service_us_per_frame,
                "rss_hwm_kib": self.rss_hwm_kib,
                "rss_half_mib": rss[0],
                "rss_end_mib": rss[1],
                "rss_growth": rss[2],
                "rss_flat": self.rss_flat,
                "rss_samples": [[round(t, 2), kib] for t, kib, _ in self.rss_samples],
            },
            "baseline": {
                "frames": self.baseline_frames,
                "observe_us": self.baseline_observe_us,
                "apply_us": self.baseline_apply_us,
                "coalesced_us": self.baseline_coalesced_us,
            },
            "instances": [
                {**asdict(i), "us_per_received": i.us_per_received} for i in self.instance_figures
            ],
            "checkpoints_on_the_wire": {
                "puts": self.checkpoint_puts,
                "bytes": self.checkpoint_bytes,
                "bytes_per_applied_frame": self.checkpoint_bytes / self.applied
                if self.applied
                else math.nan,
                "zlib1_ratio_sampled": self.checkpoint_zlib_ratio,
            },
            "takeover": self.takeover,
            "router_cpu_during_load_s": self.router_cpu_load_s,
            "router_bytes_during_load": {"in": self.router_bytes_in, "out": self.router_bytes_out},
            "passes": self.passes(),
            "notes": self.notes,
        }


def _histogram_dict(h: Histogram) -> dict[str, float]:
    return {
        "p50_le": h.quantile(0.5),
        "p99_le": h.quantile(0.99),
        "mean": h.mean,
        "count": h.count,
    }


def _ms(seconds: float, *, bound: bool = False) -> str:
    if math.isnan(seconds):
        return "-"
    if math.isinf(seconds):
        return "> 5 s" if bound else "inf"
    return f"{'≤ ' if bound else ''}{1000 * seconds:.1f} ms"


def _own(value: float | None) -> str:
    """A service option as given, or the service's own default."""
    return "default" if value is None else f"{value:g}"


def format_report(r: LoadReport) -> str:
    """Human-readable report: figures, targets, and the offline baseline side by side."""
    s = r.spec
    rss = r.rss_growth()
    basis, judged = r.service_latency
    p99 = judged.quantile(0.99)
    nominal = s.robots * s.rate_hz
    cpu_share = r.service_cpu_load_s / s.duration_s
    ok = {True: "ok", False: "MISSED"}
    lines = [
        f"lessmap fleet load: {s.robots} robots × {s.rate_hz:g} Hz × {s.features} features "
        f"(mean {r.features_mean:.1f}/frame, landmark spacing {r.landmark_spacing_m:g} m) "
        f"for {s.duration_s:g} s; {s.generators} generator process(es); seed {s.seed}",
        f"machine: {r.cpus} CPUs, load average {r.load_before[0]:.2f} before, "
        f"{r.load_after[0]:.2f} after (1 min)",
        f"service: {s.instances} instance(s) x {s.serve_workers} worker(s); {_own(s.shards)} "
        "shard(s), max batch frames "
        f"{_own(s.max_batch_frames)}, batch linger {_own(s.batch_linger_ms)} ms, "
        f"{'memory only' if s.memory_only else 'session checkpoints on'}, "
        f"method {s.method or DEFAULT_METHOD}"
        + ("; generators pinned to the last CPU" if s.pin_generators else ""),
        "",
        f"frames      offered {r.offered}  applied {r.applied}  LOST {r.lost}  missing "
        f"{r.missing}  duplicate {r.duplicate}  rejected {r.rejected}  "
        f"(sessions reported {r.sessions_reported}/{s.robots}, drained {r.drained})",
        f"offered     {r.offered / s.duration_s:.0f} frames/s (nominal {nominal:.0f}); generator "
        f"lateness max {_ms(r.lateness_max_s)}, {r.late_frames} frame(s) over one period late; "
        f"generator CPU {r.generator_cpu_s:.1f} s",
        f"decisions   {r.decisions:.0f} ({r.frames_per_decision:.2f} frames/decision, "
        f"{r.coalesced_batches:.0f} coalesced); transitions {r.transitions_service} "
        f"(received {r.transitions_received}, {len(r.robots_with_transitions)} robots)",
        f"drain       {r.drain_s:.1f} s from the last publish until every session was closed",
        "",
        "latency (what each measures)                                p50        p99        max",
        f"  queue wait: receipt in the service -> its worker round    "
        f"{_ms(r.queue_latency.quantile(0.5), bound=True):>9}  "
        f"{_ms(r.queue_latency.quantile(0.99), bound=True):>9}  "
        f"(histogram, n={r.queue_latency.count:.0f}, mean {_ms(r.queue_latency.mean)})",
        "  receipt -> end of the decision covering it, all frames  "
        + (
            f"{_ms(r.frame_latency.quantile(0.5), bound=True):>9}  "
            f"{_ms(r.frame_latency.quantile(0.99), bound=True):>9}  "
            f"(histogram, n={r.frame_latency.count:.0f}, mean {_ms(r.frame_latency.mean)})"
            if r.frame_latency.count
            else "(lessmap_frame_latency_seconds not exported by this service)"
        ),
        f"  one spectral decision (apply excluded)                   "
        f"{_ms(r.decision_seconds.quantile(0.5), bound=True):>9}  "
        f"{_ms(r.decision_seconds.quantile(0.99), bound=True):>9}  "
        f"(histogram, n={r.decision_seconds.count:.0f}, mean {_ms(r.decision_seconds.mean)})",
        f"  publish -> Transition received, transition frames only  {_ms(r.e2e(0.5)):>9}  "
        f"{_ms(r.e2e(0.99)):>9}  {_ms(r.e2e_s[-1] if r.e2e_s else math.nan):>9}  "
        f"(n={len(r.e2e_s)})",
        "",
        f"service     CPU {r.service_cpu_s:.1f} s ({100 * cpu_share:.0f} % of one core during "
        f"the load), {r.service_us_per_frame:.0f} µs per applied frame",
        f"            CPU by thread since start (s): {_threads_line(r.service_threads_cpu_s)}",
        f"            RSS peak (VmHWM) {r.rss_hwm_kib / 1024:.0f} MiB; RSS {rss[0]:.0f} MiB at "
        f"half-time ({s.warmup_s:g} s) -> {rss[1]:.0f} MiB at the end of the load "
        f"({100 * rss[2]:+.1f} %): {'flat' if r.rss_flat else 'GROWING'}",
        f"            RSS samples (s: MiB) {_rss_line(r.rss_samples)}",
        "",
        f"baseline    same streams, core ({s.method or DEFAULT_METHOD}) in this process, its "
        f"thread's CPU ({r.baseline_frames} frames of {r.baseline_robots} robots):",
        f"  core observe (apply + decide every frame)   {r.baseline_observe_us:8.0f} µs/frame",
        f"  core apply only (areas: all of its work)    {r.baseline_apply_us:8.0f} µs/frame",
        f"  core at the service's coalescing ({r.frames_per_decision:.2f} f/d)  "
        f"{r.baseline_coalesced_us:8.0f} µs/frame",
        f"  service CPU per applied frame               {r.service_us_per_frame:8.0f} µs/frame  "
        f"= {_ratio(r.service_us_per_frame, r.baseline_coalesced_us)} the core at the same "
        f"coalescing, {_ratio(r.service_us_per_frame, r.baseline_observe_us)} core observe",
        "",
        f"targets     lost 0: {ok[r.lost == 0 and r.drained]};  p99 {basis} ≤ 250 ms: "
        f"{ok[p99 <= _QUEUE_P99_TARGET_S]};  p99 publish->transition ≤ 250 ms: "
        f"{ok[r.e2e(0.99) <= _QUEUE_P99_TARGET_S] if r.e2e_s else 'no transitions'};  "
        f"RSS flat: {ok[r.rss_flat]}",
    ]
    lines += _instance_lines(r)
    lines += _takeover_lines(r)
    lines += [f"note        {note}" for note in r.notes]
    return "\n".join(lines) + "\n"


def _instance_lines(r: LoadReport) -> list[str]:
    """Per instance: its robots' frames next to what it received; checkpoints shipped."""
    if len(r.instance_figures) < 2:
        return []
    lines = [
        "",
        "instances   robots at start = robots of the partitions it owned; offered = their frames"
        " (+1 SessionEnd each, also counted as received)",
        "  instance              robots  parts  offered(+ends)   received   foreign    applied"
        "  recovered  ckpt ship/recv  moves in/out  CPU s  µs/received",
    ]
    for i in r.instance_figures:
        lines.append(
            f"  {i.name + (' (killed)' if i.killed else ''):<20}  {i.robots:6d}  "
            f"{i.partitions_at_start:3d}>{i.partitions_owned:<2.0f} "
            f"{i.frames_offered:7d} (+{i.robots:3d})  {i.received:9.0f}  {i.foreign:8.0f}  "
            f"{i.applied:9.0f}  {i.recovered:9.0f}  {i.checkpoints_shipped:6.0f}/"
            f"{i.checkpoints_received:<6.0f}  {i.moves_in:5.0f}/{i.moves_out:<5.0f}  "
            f"{i.cpu_load_s:5.1f}  {i.us_per_received:10.0f}"
        )
    received = sum(i.received for i in r.instance_figures)
    expected = r.offered + r.spec.robots
    foreign = sum(i.foreign for i in r.instance_figures)
    lines.append(
        f"  sum: received {received:.0f} of {expected} frames + SessionEnds offered "
        f"({received / expected:.4f}×), foreign {foreign:.0f}"
        + ("" if r.takeover is None else " (a kill run: catch-up replies are not 'received')")
    )
    lines.append(
        f"  router: CPU {r.router_cpu_load_s:.1f} s during the load "
        f"({100 * r.router_cpu_load_s / r.spec.duration_s:.0f} % of one core), "
        f"{1e6 * r.router_cpu_load_s / max(1, r.offered):.0f} µs per frame offered; "
        f"TCP bytes in {r.router_bytes_in / 1e6:.1f} MB / out {r.router_bytes_out / 1e6:.1f} MB "
        f"({r.router_bytes_in / max(1, r.offered):.0f} / "
        f"{r.router_bytes_out / max(1, r.offered):.0f} bytes per frame offered; on one host "
        "payloads over 3 KiB, the checkpoints, go through shared memory instead)"
    )
    if r.checkpoint_puts:
        lines.append(
            f"  checkpoints on the wire (lessmap/v4/@/checkpoints/**, seen by the benchmark): "
            f"{r.checkpoint_puts} puts, {r.checkpoint_bytes / 1e6:.2f} MB, "
            f"{r.checkpoint_bytes / max(1, r.checkpoint_puts) / 1024:.1f} KiB each, "
            f"{r.checkpoint_bytes / max(1, r.applied):.0f} bytes per applied frame; "
            f"zlib level 1 would make them {r.checkpoint_zlib_ratio:.2f}× (every tenth sampled)"
        )
    return lines


def _takeover_lines(r: LoadReport) -> list[str]:
    t = r.takeover
    if t is None:
        return []
    served = t["served_again_s"]
    return [
        "",
        f"take-over   kill -9 of {t['victim']} at {r.spec.kill_after_s:g} s: "
        f"{t['moved_robots']} robots on {t['partitions_moved']} partitions moved",
        f"  served again (a survivor applied a frame sent after the kill), s after the kill: "
        f"p50 {served['p50']:.2f}, p90 {served['p90']:.2f}, max {served['max']:.2f}, "
        f"min {served['min']:.2f} (n={served['n']}, poll every {t['poll_s']:g} s, "
        f"{t['polls']} polls); never: {len(t['unresolved'])}",
        f"  survivors own every partition again after {t['partitions_back_s']:.2f} s; "
        f"take-overs logged (partitions, ms, checkpoints fetched): {t['took_ms']}",
    ]


def _threads_line(by_name: dict[str, float], top: int = 8) -> str:
    return ", ".join(f"{name} {cpu:.1f}" for name, cpu in list(by_name.items())[:top]) or "-"


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}×" if b and not math.isnan(a) and not math.isnan(b) else "-"


def _rss_line(samples: list[tuple[float, int, float]], points: int = 12) -> str:
    if not samples:
        return "-"
    step = max(1, len(samples) // points)
    return ", ".join(f"{t:.0f}: {kib / 1024:.0f}" for t, kib, _ in samples[::step])


# -- the knee table ---------------------------------------------------------------------------


KNEE_HEADER = (
    "robots  offered/s  lost  svc p99     e2e p99   frames/dec  CPU %  RSS MiB (growth)  "
    "drain s  load  pass"
)


def knee_row(r: LoadReport) -> str:
    """One line of the knee table."""
    rss = r.rss_growth()
    return (
        f"{r.spec.robots:6d}  {r.offered / r.spec.duration_s:9.0f}  {r.lost:4d}  "
        f"{_ms(r.service_latency[1].quantile(0.99), bound=True):>9}  {_ms(r.e2e(0.99)):>8}  "
        f"{r.frames_per_decision:10.2f}  {100 * r.service_cpu_load_s / r.spec.duration_s:5.0f}  "
        f"{rss[1]:7.0f} ({100 * rss[2]:+5.1f} %)  {r.drain_s:7.1f}  {r.load_after[0]:4.1f}  "
        f"{'yes' if r.passes() else 'no'}"
    )


# -- JSON ------------------------------------------------------------------------------------


def _json(data: Any) -> str:
    """Strict JSON: NaN and infinities (no data, or past the last bucket) become null."""

    def finite(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {key: finite(item) for key, item in value.items()}
        if isinstance(value, list | tuple):
            return [finite(item) for item in value]
        return value

    return json.dumps(finite(data), allow_nan=False)

"""Client-side subcommands of ``lessmap``: replay, watch, status (wired in by ``lessmap.cli``)."""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap_client.cli_options import (
    add_deprecated_alias,
    add_zenoh_options,
    non_negative_float,
    positive_float,
    zenoh_options,
)

if TYPE_CHECKING:
    from lessmap_client.adapters.replay import ReplayStats
    from lessmap_client.fleet import FleetClient
    from lessmap_client.subscription import Subscription
    from lessmap_client.watch import FleetView
    from lessmap_schemas.messages import Error, Health, SessionState, Transition


def configure_replay(rep: argparse.ArgumentParser) -> None:
    """Define ``lessmap replay`` (run by ``run_replay``)."""
    rep.description = (
        "Publish FILE.frames.jsonl paced by its stamps (--speed), or as fast as "
        "possible (--fast). Each robot in the file gets its own publisher and session. "
        "The whole file is checked before anything is published. At the end, the service's "
        "own counts are read back: the JSON summary on stdout has, per robot, the frames "
        "offered, applied, missing and rejected; the exit code is 0 only when the service "
        "applied every frame offered, with none missing or rejected."
    )
    rep.add_argument("file", type=Path, metavar="FILE")
    rep.add_argument("--fleet", default="replay", help="fleet name (default: replay)")
    rep.add_argument("--robot-prefix", default="", help="prefix for the file's robot ids")
    pace = rep.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=positive_float, default=1.0, help="playback rate")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    rep.add_argument(
        "--settle",
        type=positive_float,
        default=10.0,
        metavar="S",
        help="after publishing, wait for the service's final counts until they have not "
        "changed for S seconds",
    )
    rep.add_argument(
        "--progress",
        type=non_negative_float,
        default=5.0,
        metavar="S",
        help="a progress line on stderr every S seconds (0: none)",
    )
    group = add_zenoh_options(rep)
    add_deprecated_alias(
        group,
        "--wait-service",
        use="--connect-timeout",
        dest="connect_timeout",
        type=positive_float,
    )


def configure_watch(watch: argparse.ArgumentParser) -> None:
    """Define ``lessmap watch`` (run by ``run_watch``)."""
    watch.add_argument("--fleet", default="*", help="fleet to follow (default: all)")
    watch.add_argument(
        "--duration",
        type=non_negative_float,
        metavar="S",
        help="stop after S seconds, the wait for a router included (default: until Ctrl-C)",
    )
    watch.add_argument(
        "--interval", type=positive_float, default=1.0, metavar="S", help="refresh period"
    )
    watch.add_argument(
        "--shared-features",
        action="store_true",
        help="the fleet's feature ids are global: show each robot's place (its fleet area, "
        "named robot:area by its first member) and the places robots share, from "
        "fleet_area_graph every --places-interval seconds (needs one --fleet)",
    )
    watch.add_argument(
        "--places-interval",
        type=positive_float,
        default=5.0,
        metavar="S",
        help="seconds between two fleet area queries",
    )
    add_zenoh_options(watch)


def run_replay(args: argparse.Namespace) -> int:
    """Run ``lessmap replay``."""
    from lessmap_client.adapters.replay import (
        ProgressReporter,
        ReplayStats,
        read_recorded,
        replay,
        settled_states,
    )
    from lessmap_schemas.framesfile import sparse_frames_warning

    net = zenoh_options(args)
    # Every line is checked before the first frame goes out.
    frames = list(read_recorded(args.file, robot_prefix=args.robot_prefix))
    if not frames:
        sys.stderr.write(f"lessmap replay: {args.file}: no frames to publish\n")
        return 1
    features = sum(len(frame.features) for frame in frames)
    warning = sparse_frames_warning(str(args.file), len(frames), features)
    if warning is not None:
        sys.stderr.write(f"lessmap replay: {warning}\n")
    stats = ReplayStats()
    batches = Batches()
    with net.connection() as conn:
        served = conn.wait_for_service(net.connect_timeout_s)
        if not served:
            sys.stderr.write("lessmap replay: no lessmap service answered; publishing anyway\n")
        reports = conn.subscribe_errors(args.fleet)
        decisions = conn.subscribe_transitions(args.fleet, history=False, handler=batches.add)

        def sessions() -> set[tuple[str, str]]:
            return {(name, r.session_id) for name, r in dict(stats.per_robot).items()}

        def acknowledged() -> int:
            ours = sessions()
            states = conn.states(args.fleet, timeout_s=1.0)
            return sum(s.frames_applied for s in states if (s.robot, s.session) in ours)

        def say(line: str) -> None:
            sys.stderr.write(f"lessmap replay: {line}\n")
            sys.stderr.flush()

        reporter = ProgressReporter(
            args.progress, lambda: stats.frames, acknowledged, say, len(frames)
        ).start()
        try:
            replay(
                frames,
                conn,
                args.fleet,
                speed=None if args.fast else args.speed,
                robot_prefix=args.robot_prefix,
                stats=stats,
                # Each robot's first frame waits until its partition's owner can hear it.
                wait_service_s=net.connect_timeout_s if served else 0.0,
            )
            final = settled_states(
                lambda: conn.states(args.fleet, timeout_s=1.0), stats, quiet_s=args.settle
            )
        finally:
            reporter.stop()
        counted = _count_reports(reports, sessions())
        decisions.close()
    summary, problems = replay_summary(stats, final, counted)
    summary["coalesced"] = batches.coalesced(sessions())
    sys.stdout.write(json.dumps(summary) + "\n")
    if summary["coalesced"]["transitions"]:
        sys.stderr.write(f"lessmap replay: {coalescing_note(summary['coalesced'])}\n")
    if problems:
        sys.stderr.write(
            "lessmap replay: the service did not apply every frame offered: "
            + ", ".join(problems)
            + "\n"
        )
        return 1
    return 0


class Batches:
    """The frames each transition's decision covered, as the service reports them."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: list[tuple[str, str, int]] = []  # robot, session, batch_frames

    def add(self, transition: Transition) -> None:
        """Note one transition (called on the subscription's thread)."""
        with self._lock:
            self._seen.append((transition.robot, transition.session, transition.batch_frames))

    def coalesced(self, sessions: set[tuple[str, str]]) -> dict[str, int]:
        """Return how many of the sessions' transitions were decided over several frames."""
        with self._lock:
            batches = [b for robot, session, b in self._seen if (robot, session) in sessions]
        over = [b for b in batches if b > 1]
        return {
            "transitions": len(over),
            "of": len(batches),
            "largest_batch_frames": max(over, default=1),
        }


def coalescing_note(coalesced: dict[str, int]) -> str:
    """Say that the service decided over batches of frames, and what that changes."""
    return (
        f"the service was behind and decided over batches of frames (up to "
        f"{coalesced['largest_batch_frames']} a decision; {coalesced['transitions']} of the "
        f"{coalesced['of']} transitions seen): fewer decisions find fewer transitions than "
        "lessmap segment does on the same file; replay at a --speed the service keeps up with "
        "to compare"
    )


def _count_reports(
    reports: Subscription[Error], sessions: set[tuple[str, str]]
) -> dict[str, dict[str, int]]:
    """Drain the error subscription: reports per robot and code, for the replayed sessions."""
    counted: dict[str, dict[str, int]] = {}
    while (report := reports.try_recv()) is not None:
        if report.robot is not None and (report.robot, report.session) in sessions:
            codes = counted.setdefault(report.robot, {})
            codes[str(report.code)] = codes.get(str(report.code), 0) + 1
    reports.close()
    return counted


def replay_summary(
    stats: ReplayStats,
    final: dict[str, SessionState],
    reports: dict[str, dict[str, int]],
) -> tuple[dict[str, Any], list[str]]:
    """Return the JSON summary and, per robot the service failed, what went wrong."""
    robots: dict[str, Any] = {}
    problems: list[str] = []
    for name, record in sorted(stats.per_robot.items()):
        state = final.get(name)
        entry: dict[str, Any] = {
            "session": record.session_id,
            "offered": record.offered,
            "applied": None if state is None else state.frames_applied,
            "missing": None if state is None else state.frames_missing,
            "rejected": None if state is None else state.frames_rejected,
            "duplicate": None if state is None else state.frames_duplicate,
            "transitions": None if state is None else state.transitions,
            "closed_by_service": record.closed_by_service,
            "skipped": record.skipped,
            "errors": reports.get(name, {}),
        }
        robots[name] = entry
        wrong = []
        if state is None:
            wrong.append("no final state from the service")
        else:
            if state.open:
                wrong.append("session still open")
            if state.frames_missing:
                wrong.append(f"{state.frames_missing} missing")
            if state.frames_rejected:
                wrong.append(f"{state.frames_rejected} rejected")
            if state.frames_applied != record.offered:
                wrong.append(f"{state.frames_applied} of {record.offered} applied")
        if record.closed_by_service or reports.get(name, {}).get("SESSION_CLOSED"):
            wrong.append("session closed by the service")
        if record.skipped:
            wrong.append(f"{record.skipped} not sent")
        if wrong:
            problems.append(f"{name} ({', '.join(wrong)})")
    applied = sum(e["applied"] or 0 for e in robots.values())
    summary = {
        "frames": stats.frames,
        "robots": stats.robots,
        "elapsed_s": round(stats.elapsed_s, 3),
        "applied": applied,
        "ok": not problems,
        "per_robot": robots,
    }
    return summary, problems


def run_watch(args: argparse.Namespace) -> int:
    """Run ``lessmap watch``."""
    from lessmap_client.fleet import FleetClient
    from lessmap_client.watch import FleetView

    if args.shared_features and "*" in args.fleet:
        sys.stderr.write("lessmap watch: --shared-features follows one fleet: give --fleet\n")
        return 1
    view = FleetView()
    net = zenoh_options(args)
    started = time.monotonic()
    # --duration bounds the whole run, the wait for a router included.
    wait_s = net.connect_timeout_s
    if args.duration is not None:
        wait_s = min(wait_s, args.duration)
    with (
        net.open_session(timeout_s=wait_s) as session,
        FleetClient(args.fleet, session=session) as client,
    ):
        left_s = None if args.duration is None else args.duration - (time.monotonic() - started)
        follow(
            client,
            view,
            None if left_s is None else max(0.0, left_s),
            args.interval,
            title=f"lessmap watch {args.fleet}",
            places_every_s=args.places_interval if args.shared_features else None,
        )
    sys.stdout.write(view.table() + "\n")
    return 0


def follow(
    client: FleetClient,
    view: FleetView,
    duration_s: float | None,
    interval_s: float,
    title: str,
    fleet: str | None = None,
    places_every_s: float | None = None,
) -> None:
    """Feed the view from the client until ``duration_s`` passes (or Ctrl-C).

    With ``places_every_s``, also the fleet's places (``fleet_area_graph`` with shared
    features) that often: a query for every robot's graph, so less often than states.
    """
    from lessmap_client.fleet_areas import FleetParams

    tty = sys.stdout.isatty()
    deadline = None if duration_s is None else time.monotonic() + duration_s
    next_refresh = next_places = 0.0
    try:
        while deadline is None or time.monotonic() < deadline:
            transition = client.next_transition(timeout_s=0.1)
            if transition is not None:
                line = view.add_transition(transition)
                if not tty:
                    sys.stdout.write(line + "\n")
                    sys.stdout.flush()
            now = time.monotonic()
            if now >= next_refresh:
                next_refresh = now + interval_s
                for state in client.states(fleet, timeout_s=0.5):
                    view.add_state(state)
                if places_every_s is not None and now >= next_places:
                    next_places = now + places_every_s
                    places = fleet or client.fleet
                    graph = client.fleet_area_graph(
                        places, params=FleetParams(shared_features=True), timeout_s=0.5
                    )
                    view.add_fleet_graph(places, graph)
                if tty:
                    sys.stdout.write("\x1b[2J\x1b[H" + view.screen(title) + "\n")
                    sys.stdout.flush()
    except KeyboardInterrupt:
        pass


# -- lessmap status --------------------------------------------------------------------------


def configure_status(status: argparse.ArgumentParser) -> None:
    """Define ``lessmap status`` (run by ``run_status``)."""
    from lessmap_schemas.partition import PARTITIONS

    status.description = (
        "Show the running lessmap service: its live instances (liveliness tokens) with their "
        "Health (version, uptime, sessions, queue depth, lag, partitions owned and shadowed), "
        f"then which of the {PARTITIONS} partitions each instance owns and stands by for "
        "(as ranges) as every participant computes them (rendezvous hashing over the live "
        "instances), and the partitions whose owner does not say it serves them. A "
        "disagreement (an owner that has not taken its partition yet, an instance still "
        "serving a partition it no longer owns) is flagged; it is normal for a moment after "
        "an instance joins or leaves. --json lists every partition. Exit code 1 when no "
        "instance answers."
    )
    status.add_argument("--json", action="store_true", help="print one JSON object")
    status.add_argument(
        "--timeout",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="seconds to wait for liveliness and Health replies",
    )
    add_zenoh_options(status)


def run_status(args: argparse.Namespace) -> int:
    """Run ``lessmap status``."""
    net = zenoh_options(args)
    with net.connection() as conn:
        live = conn.instances(args.timeout)
        healths = conn.health(args.timeout)
    if not live and not healths:
        sys.stderr.write(
            f"lessmap status: no lessmap instance answered at {net.where} "
            f"within {args.timeout:g} s\n"
        )
        return 1
    report = status_report(live, healths)
    if args.json:
        sys.stdout.write(json.dumps(report) + "\n")
    else:
        sys.stdout.write(render_status(report))
    return 0


def status_report(live: list[str], healths: list[Health]) -> dict[str, Any]:
    """Compare the rendezvous assignment over ``live`` with what each instance reports.

    Returns the JSON object ``lessmap status --json`` prints: ``instances`` (one entry per
    instance with a token or a Health reply), ``partitions`` (owner, standby, and the flags
    of each partition), ``disagreements`` (partitions with a flag) and ``ok``.
    """
    from lessmap_schemas.partition import assignment

    by_name: dict[str, Health] = {}
    for health in healths:  # an instance answering twice (two routes): keep one
        by_name.setdefault(health.instance, health)
    alive = sorted(set(live))
    table = assignment(alive)
    instances = []
    for name in sorted(set(alive) | set(by_name)):
        h = by_name.get(name)
        should_own = sorted(p for p, (owner, _) in table.items() if owner == name)
        instances.append(
            {
                "instance": name,
                "alive": name in alive,
                "health": h is not None,
                "version": None if h is None else h.version,
                "uptime_s": None if h is None else round(h.uptime_s, 3),
                "sessions": None if h is None else h.sessions,
                "frames_applied": None if h is None else h.frames_applied,
                "queue_depth": None if h is None else h.queue_depth,
                "lag_s": None if h is None else round(h.lag_s, 3),
                "partitions": None if h is None else list(h.partitions),
                "standby": None if h is None else list(h.standby),
                "owned": None if h is None else len(h.partitions),
                "standby_count": None if h is None else len(h.standby),
                "should_own": len(should_own),
            }
        )
    partitions = []
    for p, (owner, standby) in sorted(table.items()):
        holders = sorted(n for n, h in by_name.items() if p in h.partitions)
        flags = []
        owner_health = None if owner is None else by_name.get(owner)
        if owner is None:
            flags.append("no owner: no instance is alive")
        elif owner_health is None:
            flags.append(f"owner {owner} did not answer the Health query")
        elif p not in owner_health.partitions:
            flags.append(f"owner {owner} has not taken it yet")
        for other in holders:
            if other != owner:
                flags.append(f"{other} still serves it")
        partitions.append(
            {
                "partition": p,
                "owner": owner,
                "standby": standby,
                "owner_agrees": None if owner_health is None else p in owner_health.partitions,
                "served_by": holders,
                "flags": flags,
            }
        )
    for entry in instances:
        if not entry["alive"]:
            entry["note"] = "answers Health but has no liveliness token"
        elif not entry["health"]:
            entry["note"] = "alive but did not answer the Health query"
    disagreements = sum(1 for entry in partitions if entry["flags"])
    return {
        "instances": instances,
        "partitions": partitions,
        "disagreements": disagreements,
        "ok": disagreements == 0,
    }


def render_status(report: dict[str, Any]) -> str:
    """Render a ``status_report`` as the text tables of ``lessmap status``."""

    def cell(value: object) -> str:
        return "-" if value is None else str(value)

    head = ["instance", "version", "uptime_s", "sessions", "queue", "lag_s", "owns", "standby"]
    rows = [
        [
            entry["instance"],
            cell(entry["version"]),
            cell(entry["uptime_s"]),
            cell(entry["sessions"]),
            cell(entry["queue_depth"]),
            cell(entry["lag_s"]),
            f"{cell(entry['owned'])}/{entry['should_own']}",
            cell(entry["standby_count"]),
        ]
        for entry in report["instances"]
    ]
    lines = _table(head, rows)
    for entry in report["instances"]:
        if "note" in entry:
            lines.append(f"  ! {entry['instance']}: {entry['note']}")
    # Partitions as ranges per instance and per problem, not one line per partition: the
    # count is fixed by the contract (hundreds); ``--json`` has every partition.
    owned: dict[str | None, list[int]] = {}
    shadowed: dict[str | None, list[int]] = {}
    problems: dict[str, list[int]] = {}
    for entry in report["partitions"]:
        owned.setdefault(entry["owner"], []).append(entry["partition"])
        shadowed.setdefault(entry["standby"], []).append(entry["partition"])
        if entry["flags"]:
            problems.setdefault("; ".join(entry["flags"]), []).append(entry["partition"])
    lines.append("")
    lines.append("partitions by instance (rendezvous ranking over the live instances):")
    for name in sorted(n for n in {*owned, *shadowed} if n is not None):
        mine, backup = owned.get(name, []), shadowed.get(name, [])
        lines += _wrapped(f"  {name} owns {len(mine)}", mine)
        lines += _wrapped(f"  {name} stands by for {len(backup)}", backup)
    if None in owned:
        lines += _wrapped(f"  without an owner {len(owned[None])}", owned[None])
    if problems:
        lines.append("")
        lines.append("disagreements:")
        for problem, partitions in problems.items():
            lines += _wrapped(f"  {problem} ({len(partitions)})", partitions)
    total = len(report["partitions"])
    bad = report["disagreements"]
    lines.append("")
    lines.append(
        f"{total - bad} of {total} partitions served as the live instances rank them"
        + (f"; {bad} disagree (normal for a moment after a join or a leave)" if bad else "")
    )
    return "\n".join(lines) + "\n"


def _ranges(partitions: list[int], sep: str = ",") -> str:
    """'0-3,7,9-10' for [0, 1, 2, 3, 7, 9, 10]; '-' for none."""
    runs: list[list[int]] = []
    for p in sorted(partitions):
        if runs and p == runs[-1][1] + 1:
            runs[-1][1] = p
        else:
            runs.append([p, p])
    return sep.join(str(a) if a == b else f"{a}-{b}" for a, b in runs) or "-"


def _wrapped(label: str, partitions: list[int], width: int = 100) -> list[str]:
    """``label: ranges``, wrapped under the ranges at ``width`` columns."""
    head = f"{label}: "
    return textwrap.wrap(
        _ranges(partitions, ", "),
        width=max(width, len(head) + 20),
        initial_indent=head,
        subsequent_indent=" " * len(head),
        break_on_hyphens=False,
        break_long_words=False,
    )


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    return [
        "  ".join(value.ljust(width) for value, width in zip(row, widths, strict=True)).rstrip()
        for row in [head, *rows]
    ]

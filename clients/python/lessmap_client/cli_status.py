"""``lessmap status``: the live instances, and who owns and stands by for each partition."""

from __future__ import annotations

import json
import sys
import textwrap
from typing import TYPE_CHECKING, Any

from lessmap_client.cli_options import add_zenoh_options, positive_float, zenoh_options

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable

    from lessmap_schemas.messages import Health

    #: Shows a ``status_report`` (``lessmap status`` on a terminal).
    Show = Callable[[dict[str, Any]], None]


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


def run_status(args: argparse.Namespace, show: Show | None = None) -> int:
    """Run ``lessmap status``: JSON, the text tables, or ``show`` the report."""
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
    elif show is not None:
        show(report)
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
    lines = _table(STATUS_COLUMNS, status_rows(report))
    lines += status_notes(report)
    return "\n".join(lines + partition_lines(report)) + "\n"


STATUS_COLUMNS = [
    "instance",
    "version",
    "uptime_s",
    "sessions",
    "queue",
    "lag_s",
    "owns",
    "standby",
]


def status_rows(report: dict[str, Any]) -> list[list[str]]:
    """The instances of a ``status_report`` as rows of ``STATUS_COLUMNS``."""

    def cell(value: object) -> str:
        return "-" if value is None else str(value)

    return [
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


def status_notes(report: dict[str, Any]) -> list[str]:
    """What is wrong with an instance of a ``status_report``, a line each."""
    return [f"  ! {e['instance']}: {e['note']}" for e in report["instances"] if "note" in e]


def partition_lines(report: dict[str, Any]) -> list[str]:
    """The partitions of a ``status_report`` as ranges per instance, then disagreements."""
    lines: list[str] = []
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
    return lines


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

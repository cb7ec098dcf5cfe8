"""Session flood: RSS before, at the peak and after 10,000 one-frame sessions are evicted.

Run from the repository root: ``python -m benchmarks.session_flood``. For each variant
it starts one ``lessmap serve`` (its own state directory, idle timeout 2 s) on a random free
loopback port, sends a warm-up wave of 200 one-frame robots and waits for their eviction
(RSS *before*), then floods ``--robots`` one-frame robots, samples RSS until all are opened
(*peak*), waits for every eviction and ``--settle`` seconds (*after*). Then a new robot puts
one frame: the time until a ``state`` query answers with its frame applied is printed as
*new robot s* (query polling every 10 ms, so within ~10 ms of the service's own time).

Variants differ only by the service's environment (``--variants``, comma separated):

- ``shipped``: ``lessmap serve`` as it starts by default: it restarts itself with
  ``PYTHONMALLOC=malloc`` and sets glibc's malloc options (``lessmap.runtime.memory``);
- ``baseline``: ``PYTHONMALLOC=pymalloc GLIBC_TUNABLES=`` (CPython's and glibc's defaults:
  both settings are the operator's way to keep their own);
- ``mallopt-only``: ``PYTHONMALLOC=pymalloc`` (glibc options set, pymalloc kept);
- ``malloc-only``: ``GLIBC_TUNABLES=`` (system malloc, glibc's default options);
- anything else is read as environment assignments joined by ``+``, e.g.
  ``PYTHONMALLOC=malloc+GLIBC_TUNABLES=+MALLOC_ARENA_MAX=1``.

Per variant it prints RSS before/peak/after in MiB, after/before, the share of the peak's
growth left, which mappings the growth from before to after sits in (``[heap]`` = main arena,
64 MiB-reserved anonymous regions = per-thread glibc arenas, other anonymous, files) and
the new robot's wait, and *flood s*: from the first put until every session is open (what the
allocator costs in throughput). Every process is stopped by its PID.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import zenoh

from benchmarks.fleet.process import free_port, proc_status_kib, stop_process
from lessmap_client.session import open_session, wait_for_service
from lessmap_schemas import keys
from lessmap_schemas.codec import encode
from lessmap_schemas.messages import Frame
from tests.conftest import metric_value, new_robot_wait_s

VARIANTS: dict[str, dict[str, str]] = {
    "shipped": {},
    "baseline": {"PYTHONMALLOC": "pymalloc", "GLIBC_TUNABLES": ""},
    "mallopt-only": {"PYTHONMALLOC": "pymalloc"},
    "malloc-only": {"GLIBC_TUNABLES": ""},
}
WARM_ROBOTS = 200
_ARENA_KIB = 65536  # a glibc per-thread arena reserves HEAP_MAX_SIZE (64 MiB) of addresses

BLOCK = zenoh.CongestionControl.BLOCK  # a burst of puts must not be dropped at the sender


def memory_map(pid: int) -> dict[str, int]:
    """Resident KiB of a process by kind of mapping (/proc/PID/smaps).

    ``heap``: the main arena (brk); ``arenas``: per-thread glibc arenas (anonymous mappings
    whose reserved size, with their neighbouring guard, is 64 MiB); ``anon``: other anonymous
    memory (pymalloc arenas, large mallocs, thread stacks, Rust); ``file``: mapped files.
    """
    out = {"heap": 0, "arenas": 0, "anon": 0, "file": 0}
    regions: list[tuple[int, int, str, int]] = []  # start, end, name, rss KiB
    name = ""
    start = end = 0
    for line in Path(f"/proc/{pid}/smaps").read_text().splitlines():
        first = line.split(maxsplit=1)[0]
        if "-" in first and not first.endswith(":"):
            lo_hex, hi_hex = first.split("-")
            start, end = int(lo_hex, 16), int(hi_hex, 16)
            parts = line.split(maxsplit=5)
            name = parts[5] if len(parts) > 5 else ""
        elif first == "Rss:":
            regions.append((start, end, name, int(line.split()[1])))
    # A thread arena is a read-write part followed by its PROT_NONE rest: adjacent, 64 MiB.
    for index, (lo, hi, label, rss) in enumerate(regions):
        if label == "[heap]":
            out["heap"] += rss
        elif label.startswith("/"):
            out["file"] += rss
        elif not label:
            span = hi - lo
            if index + 1 < len(regions) and regions[index + 1][0] == hi:
                span += regions[index + 1][1] - regions[index + 1][0]
            is_arena = span // 1024 == _ARENA_KIB and lo % (_ARENA_KIB * 1024) == 0
            out["arenas" if is_arena else "anon"] += rss
        else:
            out["anon"] += rss  # [stack], [vvar], ...
    return out


def variant_env(variant: str) -> dict[str, str]:
    """A named variant's environment, or ``NAME=VALUE+NAME=VALUE`` given on the command line."""
    if variant in VARIANTS:
        return VARIANTS[variant]
    return dict(item.split("=", 1) for item in variant.split("+"))


def _frame(robot: int) -> bytes:
    features = [robot * 10 + k for k in range(8)]
    return encode(Frame(session="s1", seq=0, stamp_s=0.0, features=features))


def _wait(predicate: object, timeout_s: float, what: str, on_poll: object = None) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():  # type: ignore[operator]
        if on_poll is not None:
            on_poll()  # type: ignore[operator]
        if time.monotonic() > deadline:
            msg = f"timed out after {timeout_s} s waiting for {what}"
            raise RuntimeError(msg)
        time.sleep(0.05)


def run(
    variant: str, robots: int, settle_s: float, workdir: Path, *, behind_router: bool = False
) -> dict[str, float | str]:
    """Flood one fresh service; return its figures.

    ``behind_router``: the service joins a separate ``lessmap router`` as a client (a site's
    topology) instead of being the router itself, so Zenoh's routing state for the flood's
    keys lives in the router process.
    """
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    metrics_port = free_port()
    router: subprocess.Popen[bytes] | None = None
    if behind_router:
        with (workdir / f"router-{variant}.log").open("wb") as log:
            router = subprocess.Popen(
                [sys.executable, "-m", "lessmap", "router", "-l", endpoint], stdout=log, stderr=log
            )
        args = [sys.executable, "-m", "lessmap", "serve", "-m", "client", "-e", endpoint]
    else:
        args = [sys.executable, "-m", "lessmap", "serve", "-m", "router", "-l", endpoint]
    args += ["--cfg", "scouting/multicast/enabled:false", "--metrics-port", str(metrics_port)]
    args += ["--state-dir", str(workdir / f"state-{variant}"), "--idle-timeout", "2"]
    args += ["--max-sessions", str(2 * robots), "--new-sessions-per-s-per-fleet", "100000"]
    env = {**os.environ, **variant_env(variant)}
    log_path = workdir / f"serve-{variant}.log"
    with log_path.open("wb") as log:
        service = subprocess.Popen(args, stdout=log, stderr=log, env=env)
    fleet = f"flood-{uuid.uuid4().hex[:8]}"
    url = f"http://127.0.0.1:{metrics_port}/metrics"

    def metric(name: str) -> float:
        import urllib.request

        try:
            with urllib.request.urlopen(url, timeout=10) as response:
                return metric_value(response.read().decode(), name)
        except OSError:
            if service.poll() is not None:
                raise
            return -1.0

    def rss() -> int:
        return proc_status_kib(service.pid, "VmRSS")

    session: zenoh.Session | None = None
    try:
        _wait(lambda: metric("lessmap_sessions") >= 0, 60.0, "the service")
        session = open_session([endpoint], timeout_s=20.0)
        if not wait_for_service(session, 20.0):
            msg = "the service did not come up"
            raise RuntimeError(msg)
        time.sleep(0.5)  # the frames subscription reaches the client's routing
        for robot in range(WARM_ROBOTS):
            session.put(keys.frames(fleet, f"warm{robot}"), _frame(robot), congestion_control=BLOCK)
        evicted = "lessmap_sessions_evicted_total"
        _wait(lambda: metric(evicted) >= WARM_ROBOTS, 60.0, "the warm-up evicted")
        time.sleep(settle_s)
        before = rss()
        where_before = memory_map(service.pid)
        peak = before

        def sample() -> None:
            nonlocal peak
            peak = max(peak, rss())

        flood_start = time.monotonic()
        for robot in range(robots):
            session.put(keys.frames(fleet, f"r{robot}"), _frame(robot), congestion_control=BLOCK)
            if robot % 500 == 0:
                sample()
        total = WARM_ROBOTS + robots
        opened = "lessmap_sessions_opened_total"
        _wait(lambda: metric(opened) >= total, 300.0, "the flood opened", sample)
        flood_s = time.monotonic() - flood_start
        sample()
        _wait(lambda: metric(evicted) >= total, 300.0, "the flood evicted", sample)
        time.sleep(settle_s)
        after = rss()
        where = memory_map(service.pid)
        wait_s = new_robot_wait_s(session, fleet, "newcomer", _frame(1), 10.0)
        return {
            "variant": variant,
            "before": before / 1024,
            "peak": peak / 1024,
            "after": after / 1024,
            "ratio": after / before,
            "left": (after - before) / max(1, peak - before),
            "new_robot_s": wait_s,
            "flood_s": flood_s,
            **{k: (v - where_before[k]) / 1024 for k, v in where.items()},
        }
    finally:
        if session is not None:
            session.close()
        stop_process(service)
        if router is not None:
            stop_process(router)


def main() -> None:
    """Run the variants one after the other and print them side by side."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=10_000, help="one-frame robots")
    parser.add_argument("--variants", default="baseline,shipped")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each variant")
    parser.add_argument("--settle", type=float, default=3.0, help="seconds before RSS")
    parser.add_argument(
        "--behind-router",
        action="store_true",
        help="the service joins a separate lessmap router as a client (a site's topology)",
    )
    args = parser.parse_args()
    head = f"{'variant':<12} {'before':>7} {'peak':>7} {'after':>7} {'after/b':>8} {'left':>5}"
    head += f" {'heap':>6} {'arenas':>6} {'anon':>6} {'file':>6} {'new robot s':>11} {'flood s':>7}"
    print("RSS MiB; heap/arenas/anon/file: growth from before to after, by mapping")
    print(head)
    with tempfile.TemporaryDirectory(prefix="lessmap-flood-") as tmp:
        for _ in range(args.repeat):
            for variant in args.variants.split(","):
                r = run(
                    variant, args.robots, args.settle, Path(tmp), behind_router=args.behind_router
                )
                print(
                    f"{variant:<12} {r['before']:>7.0f} {r['peak']:>7.0f} {r['after']:>7.0f} "
                    f"{r['ratio']:>8.2f} {r['left']:>5.2f} {r['heap']:>6.0f} {r['arenas']:>6.0f} "
                    f"{r['anon']:>6.0f} {r['file']:>6.0f} {r['new_robot_s']:>11.3f} "
                    f"{r['flood_s']:>7.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()

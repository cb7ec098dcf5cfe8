"""py-spy collapsed stacks of the service condensed into a text summary (``--profile``)."""

from __future__ import annotations

import re


def summarize_profile(raw: str, top: int = 25) -> str:
    """Summarize py-spy raw (collapsed) stacks: share of samples by thread, self, inclusive.

    Frames are merged by function and file (line numbers dropped), so a function counts
    once however many of its lines were sampled.
    """
    own: dict[str, float] = {}
    inclusive: dict[str, float] = {}
    threads: dict[str, float] = {}
    total = 0.0
    for line in raw.splitlines():
        stack, _, count_text = line.rpartition(" ")
        if not stack or not count_text.isdigit():
            continue
        count = float(count_text)
        thread, *calls = stack.split(";")
        calls = [_LINE_NUMBER.sub(")", frame) for frame in calls] or [thread]
        total += count
        name = _THREAD_ID.sub("", thread)
        threads[name] = threads.get(name, 0.0) + count
        own[calls[-1]] = own.get(calls[-1], 0.0) + count
        for frame in set(calls):
            inclusive[frame] = inclusive.get(frame, 0.0) + count
    if not total:
        return "no samples\n"
    lines = [
        f"{total:.0f} samples of the service thread holding the GIL",
        "",
        "by thread:",
    ]
    lines += [f"  {100 * n / total:5.1f} %  {name}" for name, n in _top(threads, top)]
    lines += ["", "self time (the function itself):"]
    lines += [f"  {100 * n / total:5.1f} %  {name}" for name, n in _top(own, top)]
    lines += ["", "inclusive time (the function and what it calls):"]
    lines += [f"  {100 * n / total:5.1f} %  {name}" for name, n in _top(inclusive, top)]
    return "\n".join(lines) + "\n"


_LINE_NUMBER = re.compile(r":\d+\)$")
_THREAD_ID = re.compile(r"^thread \(\d+\): ")


def _top(counts: dict[str, float], top: int) -> list[tuple[str, float]]:
    return sorted(counts.items(), key=lambda item: -item[1])[:top]

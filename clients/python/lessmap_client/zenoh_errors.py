"""Zenoh's error texts made into one line that says what to do.

Zenoh's errors are written for its developers: Rust debug text (``Json5Err(Message {...})``)
and the source location of each layer (``at .../tcp.rs:61.``). A user needs the endpoint
at fault and the flag that changes it. Pure string functions: no Zenoh import.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

#: What a client asks when no router answers; ``lessmap ros`` asks for rmw_zenohd instead.
ROUTER_HINT = "is `lessmap serve` or `lessmap router` running there?"

_SOURCE_LOCATION = re.compile(r"\s*\bat \S+\.rs:\d+\.?")
_DEBUG_MESSAGE = re.compile(r'Message \{ msg: "(?P<msg>.*?)", location: .*?\}\)?', re.DOTALL)
_LISTENER = re.compile(r"listener bound to (?P<endpoint>\S+?):? \[")
_UNREACHED = re.compile(r"Single\((?P<endpoint>[^)]+)\)")
_ENDPOINT_FORM = re.compile(r"Endpoints must be of the form .*?: (?P<endpoint>\S+)")


def clean(text: str) -> str:
    """Return Zenoh's message without Rust source paths and debug wrappers, on one line."""
    text = _SOURCE_LOCATION.sub("", text)
    match = _DEBUG_MESSAGE.search(text)
    if match:
        text = match.group("msg")
    text = text.removeprefix("Json5Err(").removeprefix("JSON error: ")
    return " ".join(text.replace("[", " ").replace("]", " ").split()).rstrip("!. ") or "error"


def explain(text: str, *, connect: Sequence[str] = (), hint: str = ROUTER_HINT) -> str:
    """Return one line for an error of ``zenoh.open`` or of a Zenoh config: cause and remedy.

    Args:
        text: ``str()`` of the ``zenoh.ZError``.
        connect: the endpoints the session was told to connect to.
        hint: what to check when no router answers.
    """
    if "Address already in use" in text:
        match = _LISTENER.search(text)
        where = match.group("endpoint") if match else "the listen endpoint"
        return (
            f"cannot listen on {where}: the port is already in use; stop the program "
            f"that holds it or choose another port with -l/--listen"
        )
    if "Unable to connect to any of" in text:
        named = connect or [m.group("endpoint") for m in _UNREACHED.finditer(text)]
        where = ", ".join(named) or "the configured endpoints"
        return f"no Zenoh router answered at {where} (-e/--connect): {hint}"
    match = _ENDPOINT_FORM.search(text)
    if match:
        bad = _SOURCE_LOCATION.sub("", match.group("endpoint"))
        return f"invalid endpoint {bad}: expected PROTOCOL/HOST:PORT, e.g. tcp/127.0.0.1:7447"
    return clean(text)

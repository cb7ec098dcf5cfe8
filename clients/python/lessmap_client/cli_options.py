"""The command-line grammar every networked ``lessmap`` command shares, defined once.

1. ``add_zenoh_options`` adds ``-e/--connect``, ``-l/--listen``, ``-m/--mode``,
   ``-c/--zenoh-config`` (zenohd's letters) and ``--connect-timeout``: one help text and one
   default each, whatever the command.
2. ``zenoh_options(args)`` checks what was given and says where to connect: the
   ``-e`` endpoints, else the config file's, else the local router.
3. Values out of range are usage errors, found by argparse (``positive_int``, ...).
4. An old spelling stays accepted and says once on stderr which one to use.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lessmap_client.errors import ZenohConfigError
from lessmap_client.session import DEFAULT_ENDPOINT
from lessmap_client.zenoh_errors import ROUTER_HINT

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    import zenoh

    from lessmap_client.connection import Connection

#: How long every command waits for a router before giving up, unless told otherwise.
DEFAULT_CONNECT_TIMEOUT_S = 10.0
#: The modes of a client, and what each means.
CLIENT_MODES = ("client", "peer")
MODE_MEANINGS = {
    "client": "through a router (the -e endpoints), the usual",
    "peer": "also directly with other peers (give -l so they can reach it)",
    "router": "route for others, as zenohd does",
}
TITLE = "Zenoh (spelled as zenohd spells them)"
CONNECT_HELP = "Zenoh endpoint to connect to, e.g. tcp/10.0.0.5:7447"
LISTEN_HELP = "Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7448"
ZENOH_CONFIG_HELP = (
    "Zenoh config file (JSON5), e.g. a secured site's from lessmap certs; -e, -l and -m "
    "override it, and its endpoints are used unless -e or -l name others"
)
TIMEOUT_HELP = "seconds to wait for a router before giving up"


def positive_int(text: str) -> int:
    """Argparse type: a whole number of at least 1."""
    value: int = _number(text, int)
    if value < 1:
        msg = f"must be at least 1, got {text}"
        raise argparse.ArgumentTypeError(msg)
    return value


def non_negative_int(text: str) -> int:
    """Argparse type: a whole number of at least 0."""
    value: int = _number(text, int)
    if value < 0:
        msg = f"must be 0 or more, got {text}"
        raise argparse.ArgumentTypeError(msg)
    return value


def positive_float(text: str) -> float:
    """Argparse type: a finite number above 0 (seconds, a rate, a speed)."""
    value: float = _number(text, float)
    if not (value > 0 and math.isfinite(value)):
        msg = f"must be a positive number, got {text}"
        raise argparse.ArgumentTypeError(msg)
    return value


def non_negative_float(text: str) -> float:
    """Argparse type: a finite number of at least 0."""
    value: float = _number(text, float)
    if not (value >= 0 and math.isfinite(value)):
        msg = f"must be 0 or a positive number, got {text}"
        raise argparse.ArgumentTypeError(msg)
    return value


def _number(text: str, kind: Callable[[str], Any]) -> Any:
    try:
        return kind(text)
    except ValueError:
        noun = "a whole number" if kind is int else "a number"
        msg = f"expected {noun}, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from None


class DeprecatedAlias(argparse.Action):
    """An old spelling of an option: stores as the new one does, and says to use that one."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        self.use = kwargs.pop("use")
        super().__init__(option_strings, dest, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        """Store the value under the new option's name; say so on stderr."""
        sys.stderr.write(f"{parser.prog}: {option_string} is deprecated; use {self.use}\n")
        setattr(namespace, self.dest, values)


def add_deprecated_alias(
    parser: argparse.ArgumentParser | Any, alias: str, *, use: str, dest: str, **kwargs: Any
) -> None:
    """Accept ``alias`` as an old spelling of option ``use`` (hidden from ``--help``)."""
    parser.add_argument(
        alias, dest=dest, action=DeprecatedAlias, use=use, help=argparse.SUPPRESS, **kwargs
    )


def mode_help(modes: Sequence[str]) -> str:
    """Return ``-m``'s help: what each of ``modes`` means."""
    return "Zenoh mode: " + "; ".join(f"{m} = {MODE_MEANINGS[m]}" for m in modes)


def add_zenoh_options(
    parser: argparse.ArgumentParser,
    *,
    modes: Sequence[str] | None = CLIENT_MODES,
    connect: bool = True,
    zenoh_config: bool = True,
    connect_timeout: bool = True,
    notes: Mapping[str, str] | None = None,
    suppress_defaults: bool = False,
) -> Any:
    """Add the Zenoh options to ``parser``, in one help group, and return the group.

    Args:
        parser: the command's parser.
        modes: the ``-m`` choices (the first is the default), or None for no ``-m``.
        connect: add ``-e/--connect`` (a command that only listens has none).
        zenoh_config: add ``-c/--zenoh-config``.
        connect_timeout: add ``--connect-timeout`` (a command that waits for a router).
        notes: text to end the help of an option with, by its dest (e.g. its default).
        suppress_defaults: store nothing unless given (the caller merges other sources).
    """
    group = parser.add_argument_group(TITLE)
    notes = {
        "connect": f"default: {DEFAULT_ENDPOINT}, or the config file's",
        **({} if notes is None else notes),
    }

    def add(*names: str, dest: str, default: Any, help: str, **kwargs: Any) -> None:
        parts = ["repeatable"] if kwargs.get("action") == "append" else []
        parts += [notes[dest]] if dest in notes else []
        text = f"{help} ({'; '.join(parts)})" if parts else help
        default = argparse.SUPPRESS if suppress_defaults else default
        group.add_argument(*names, dest=dest, default=default, help=text, **kwargs)

    if connect:
        add(
            "-e",
            "--connect",
            dest="connect",
            default=None,
            action="append",
            metavar="ENDPOINT",
            help=CONNECT_HELP,
        )
    add(
        "-l",
        "--listen",
        dest="listen",
        default=None,
        action="append",
        metavar="ENDPOINT",
        help=LISTEN_HELP,
    )
    if modes is not None:
        add(
            "-m",
            "--mode",
            dest="mode",
            default=modes[0],
            choices=list(modes),
            help=mode_help(modes),
        )
    if zenoh_config:
        add(
            "-c",
            "--zenoh-config",
            dest="zenoh_config",
            default=None,
            metavar="FILE.json5",
            help=ZENOH_CONFIG_HELP,
        )
    if connect_timeout:
        add(
            "--connect-timeout",
            dest="connect_timeout",
            default=DEFAULT_CONNECT_TIMEOUT_S,
            type=positive_float,
            metavar="S",
            help=TIMEOUT_HELP,
        )
    return group


@dataclass(frozen=True, slots=True)
class ZenohOptions:
    """What the Zenoh options of one command say, checked."""

    connect: tuple[str, ...]
    listen: tuple[str, ...]
    mode: str
    config_file: str | None
    connect_timeout_s: float

    @property
    def where(self) -> str:
        """Where the command connects, for messages."""
        return ", ".join(self.connect) or f"the endpoints of {self.config_file}"

    def open_session(
        self, *, timeout_s: float | None = None, hint: str = ROUTER_HINT
    ) -> zenoh.Session:
        """Open a Zenoh session with these options (the caller closes it).

        Raises:
            ConnectionError: no router answered within ``timeout_s`` (default: the option).
            ZenohConfigError: the configuration is invalid, or a listen port is taken.
        """
        from lessmap_client.session import open_session

        return open_session(
            self.connect,
            self.mode,
            self.connect_timeout_s if timeout_s is None else timeout_s,
            self.config_file,
            listen=self.listen,
            hint=hint,
        )

    def connection(self, *, timeout_s: float | None = None) -> Connection:
        """Open a ``Connection`` with these options (use it as a context manager)."""
        from lessmap_client.connection import Connection
        from lessmap_client.transport import ZenohTransport

        session = self.open_session(timeout_s=timeout_s)
        return Connection(ZenohTransport(session, owned=True))


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    """Return the checked Zenoh options of a command's parsed ``args``.

    Raises:
        ZenohConfigError: the config file is missing.
    """
    config = getattr(args, "zenoh_config", None)
    if config is not None and not Path(config).is_file():
        msg = f"-c/--zenoh-config {config}: no such file"
        raise ZenohConfigError(msg)
    given = tuple(getattr(args, "connect", None) or ())
    # A config file brings its own endpoints; without one, the router on this machine.
    connect = given or (() if config is not None else (DEFAULT_ENDPOINT,))
    return ZenohOptions(
        connect=connect,
        listen=tuple(getattr(args, "listen", None) or ()),
        mode=getattr(args, "mode", None) or "client",
        config_file=None if config is None else str(config),
        connect_timeout_s=getattr(args, "connect_timeout", DEFAULT_CONNECT_TIMEOUT_S),
    )


def float_up_to(high: float) -> Callable[[str], float]:
    """Return an argparse type: a number above 0 and at most ``high`` (e.g. an angle)."""

    def check(text: str) -> float:
        value: float = _number(text, float)
        if not 0 < value <= high:
            msg = f"must be above 0 and at most {high:g}, got {text}"
            raise argparse.ArgumentTypeError(msg)
        return float(value)

    return check

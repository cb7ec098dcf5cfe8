"""``lessmap router``'s command line: the shared Zenoh options; the router is in the runtime.

A router has no mode to choose and waits for nobody: ``-l``, ``-e`` and ``-c`` only. The
old ``--config`` spelling of ``-c`` stays accepted (zenohd's long name; ``serve --config``
is lessmap's settings file, so the shared name is ``--zenoh-config``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from lessmap_client.cli_options import add_deprecated_alias, add_zenoh_options

if TYPE_CHECKING:
    import argparse

#: Where the router listens when neither ``-l`` nor the config file names an endpoint.
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def configure(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap router``."""
    parser.description = (
        "Run a plain Zenoh router (no lessmap service) in the foreground until SIGTERM/SIGINT. "
        "Service instances (lessmap serve -m client -e ENDPOINT), robots and fleet apps "
        "connect to it; routers connect to each other with -e. Multicast scouting is off "
        "unless the config file enables it."
    )
    group = add_zenoh_options(
        parser,
        modes=None,
        connect_timeout=False,
        notes={
            "connect": "another router, to form a mesh; default: none",
            "listen": f"default: {DEFAULT_LISTEN}, or the config file's",
        },
    )
    add_deprecated_alias(group, "--config", use="-c/--zenoh-config", dest="zenoh_config")
    parser.add_argument(
        "--cfg",
        action="append",
        default=[],
        metavar="KEY:VALUE",
        help="Zenoh config override, VALUE in JSON5 (repeatable)",
    )


def run(args: argparse.Namespace) -> int:
    """Run ``lessmap router`` until a stop signal; return 0 (1 is a ``ConfigError``)."""
    from pathlib import Path

    from lessmap.runtime import router

    args.config = None if args.zenoh_config is None else Path(args.zenoh_config)
    args.listen = args.listen or []
    args.connect = args.connect or []
    return router.run(args)

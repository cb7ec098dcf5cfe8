"""``lessmap view`` (a Foxglove WebSocket server) and ``lessmap record`` (an MCAP file).

Both follow one fleet with the same feed and the same channels (``lessmap.viz.scene``): what
a live Foxglove or Lichtblick shows is what the MCAP file replays later.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap.cli.foreground import StopSignal, add_run_options, stop_signals
from lessmap.errors import ConfigError

if TYPE_CHECKING:
    import argparse

    import foxglove
    from foxglove.mcap import MCAPWriter

    from lessmap.viz.feed import Channels, LateJoiners

log = logging.getLogger(__name__)

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: How long view and record wait for the lessmap router by default: they are often started
#: together with ``lessmap serve``, which can take tens of seconds to listen on a loaded
#: machine (the other foreground commands keep ``lessmap.cli.foreground``'s default).
CONNECT_TIMEOUT_S = 60.0
#: Seconds between two fleet area queries with --shared-features (each asks every robot's
#: area graph: less often than the state table's once a second).
PLACES_PERIOD_S = 5.0


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--fleet", required=True, help="the fleet to show")
    parser.add_argument(
        "-e",
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"the lessmap router (default {DEFAULT_ENDPOINT}); repeatable",
    )
    parser.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help=(
            "a Zenoh client config (JSON5), e.g. a secured site's zenoh-viewer-FLEET-mtls.json5 "
            "from lessmap certs: the viewer.FLEET identity may read the robots' frames (their "
            "poses), app.FLEET may not; its endpoints are used unless -e is given"
        ),
    )
    parser.add_argument(
        "--covgraph",
        metavar="ROBOT",
        help="also show this robot's CovGraph (its current submap, from its frames)",
    )
    parser.add_argument(
        "--shared-features",
        action="store_true",
        help="the fleet's feature ids are global: a place column in the state table (each "
        "robot's fleet area, robot:area of its first member), from the fleet's area graphs "
        "every 5 s",
    )
    add_run_options(
        parser,
        connect_timeout_s=CONNECT_TIMEOUT_S,
        connect_help="how long to wait for the lessmap router, saying so once while waiting",
    )


def configure_view(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap view``."""
    parser.description = (
        "Show a fleet in Foxglove or Lichtblick: a Foxglove WebSocket server with each "
        "robot's trajectory coloured by submap (where frames carry poses), transitions as "
        "log entries and markers, the per-robot state table and optionally a robot's "
        "CovGraph. Open ws://HOST:PORT in the app. Needs pip install 'lessmap[viz]'."
    )
    _common(parser)
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)"
    )
    parser.add_argument(
        "--port", type=int, default=8765, help="port (default 8765; 0: any free one)"
    )
    parser.add_argument("--mcap", type=Path, default=None, help="also record the channels to FILE")


def configure_record(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap record``."""
    parser.description = (
        "Record a fleet's view to an MCAP file (the channels of lessmap view), for Foxglove, "
        "Lichtblick or any MCAP reader later. Needs pip install 'lessmap[viz]'."
    )
    _common(parser)
    parser.add_argument("--mcap", type=Path, required=True, help="the MCAP file to write")
    parser.add_argument(
        "--overwrite", action="store_true", help="replace FILE if it exists (default: refuse)"
    )


def run_view(args: argparse.Namespace) -> int:
    """Serve the fleet over WebSocket until a signal or --duration."""
    with stop_signals() as stop:
        return _run_view(args, stop)


def _run_view(args: argparse.Namespace, stop: StopSignal) -> int:
    import foxglove

    from lessmap.viz.feed import Channels, LateJoiners

    # Two contexts: what is re-sent to a client that subscribes late goes to the server only,
    # not into the MCAP file of --mcap. The channels exist before the server starts.
    with_graph = args.covgraph is not None
    live = Channels(foxglove.Context(), covgraph=with_graph)
    joiners = LateJoiners()
    try:
        server = foxglove.start_server(
            name=f"lessmap {args.fleet}",
            host=args.host,
            port=args.port,
            context=live.context,
            server_listener=joiners,
        )
    except Exception as exc:  # foxglove raises its own error kinds for a taken port
        msg = f"cannot serve on {args.host}:{args.port}: {exc}"
        raise ConfigError(msg) from exc
    port = server.port  # 0 once stopped
    log.info(
        "Foxglove WebSocket server on ws://%s:%d (open it in Foxglove or Lichtblick)",
        args.host,
        port,
    )
    record = Channels(foxglove.Context(), covgraph=with_graph) if args.mcap else None
    writer = None if record is None else _open_mcap(args.mcap, record.context, overwrite=False)
    try:
        counts = _follow(args, stop, live=live, record=record, joiners=joiners)
    finally:
        if writer is not None:
            writer.close()
        server.stop()
    print(json.dumps({"fleet": args.fleet, "port": port, **counts}))
    return 0


def run_record(args: argparse.Namespace) -> int:
    """Record the fleet's channels to an MCAP file until a signal or --duration."""
    with stop_signals() as stop:
        return _run_record(args, stop)


def _run_record(args: argparse.Namespace, stop: StopSignal) -> int:
    import foxglove

    from lessmap.viz.feed import Channels

    record = Channels(foxglove.Context(), covgraph=args.covgraph is not None)
    writer = _open_mcap(args.mcap, record.context, overwrite=args.overwrite)
    try:
        counts = _follow(args, stop, record=record)
    finally:
        writer.close()
    print(json.dumps({"fleet": args.fleet, "mcap": str(args.mcap), **counts}))
    return 0


def _open_mcap(path: Path, context: foxglove.Context, *, overwrite: bool) -> MCAPWriter:
    import foxglove

    if path.exists() and not overwrite:
        msg = f"{path} exists (give --overwrite to replace it)"
        raise ConfigError(msg)
    try:
        return foxglove.open_mcap(path, allow_overwrite=overwrite, context=context)
    except Exception as exc:  # foxglove's own error kinds
        msg = f"cannot write {path}: {exc}"
        raise ConfigError(msg) from exc


def _follow(
    args: argparse.Namespace,
    stop: StopSignal,
    *,
    live: Channels | None = None,
    record: Channels | None = None,
    joiners: LateJoiners | None = None,
) -> dict[str, int]:
    from lessmap.viz.feed import FleetFeed
    from lessmap_client.connection import Connection
    from lessmap_client.session import open_session

    config = args.zenoh_config
    if config is not None and not Path(config).is_file():
        msg = f"--zenoh-config {config}: no such file"
        raise ConfigError(msg)
    endpoints = args.connect or ([] if config else [DEFAULT_ENDPOINT])
    try:
        session = open_session(endpoints, timeout_s=0, config_file=config)  # one attempt
    except ConnectionError:
        log.info(
            "waiting for the lessmap service on %s (up to %g s, --connect-timeout)",
            ", ".join(endpoints) or f"the endpoints of {config}",
            args.connect_timeout,
        )
        session = open_session(endpoints, timeout_s=args.connect_timeout, config_file=config)
    try:
        with Connection.from_session(session) as conn:
            feed = FleetFeed(
                session,
                conn,
                args.fleet,
                live=live,
                record=record,
                joiners=joiners,
                covgraph=args.covgraph,
                places_period_s=PLACES_PERIOD_S if args.shared_features else None,
            ).start()
            try:
                stop.wait(args.duration)
            finally:
                feed.stop()
            return dict(sorted(feed.counts.items()))
    finally:
        session.close()

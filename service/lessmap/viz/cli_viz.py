"""``lessmap view`` (a Foxglove WebSocket server) and ``lessmap record`` (an MCAP file).

Both follow one fleet with the same feed and the same channels (``lessmap.viz.scene``): what
a live Foxglove or Lichtblick shows is what the MCAP file replays later.
"""

from __future__ import annotations

import json
import logging
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

from lessmap.cli.foreground import StopSignal, add_run_options, stop_signals
from lessmap.errors import ConfigError
from lessmap_client.cli_options import add_zenoh_options, non_negative_int, zenoh_options

if TYPE_CHECKING:
    import argparse

    import foxglove
    import zenoh
    from foxglove.mcap import MCAPWriter

    from lessmap.viz.feed import Channels, LateJoiners

log = logging.getLogger(__name__)

#: A wait for the router longer than this is announced (once) on stderr.
ANNOUNCE_WAIT_S = 2.0
#: Seconds between two fleet area queries with --shared-features (each asks every robot's
#: area graph: less often than the state table's once a second).
PLACES_PERIOD_S = 5.0


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--fleet", required=True, help="the fleet to show")
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
    add_run_options(parser)
    add_zenoh_options(parser)


def configure_view(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap view``."""
    parser.description = (
        "Show a fleet in Foxglove or Lichtblick: a Foxglove WebSocket server with each "
        "robot's trajectory coloured by submap (where frames carry poses), transitions as "
        "log entries and markers, the per-robot state table and optionally a robot's "
        "CovGraph. Open ws://HOST:PORT in the app. On a secured site, -c takes the "
        "zenoh-viewer-FLEET-mtls.json5 of lessmap certs: the viewer.FLEET identity may read "
        "the robots' frames (their poses), app.FLEET may not. Needs pip install "
        "'lessmap[viz]'."
    )
    _common(parser)
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on")
    parser.add_argument(
        "--port", type=non_negative_int, default=8765, help="port (0: any free one)"
    )
    parser.add_argument(
        "--mcap", type=Path, default=None, metavar="FILE", help="also record the channels to FILE"
    )


def configure_record(parser: argparse.ArgumentParser) -> None:
    """Define ``lessmap record``."""
    parser.description = (
        "Record a fleet's view to an MCAP file (the channels of lessmap view), for Foxglove, "
        "Lichtblick or any MCAP reader later. Needs pip install 'lessmap[viz]'."
    )
    _common(parser)
    parser.add_argument(
        "--mcap", type=Path, required=True, metavar="FILE", help="the MCAP file to write"
    )
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
    record = Channels(foxglove.Context(), covgraph=with_graph) if args.mcap else None
    if args.mcap is not None and args.mcap.exists():
        msg = f"{args.mcap} exists (lessmap record --overwrite replaces a file)"
        raise ConfigError(msg)
    # Each step undoes itself when a later one fails: nothing is left listening or open.
    with ExitStack() as undo:
        session = _open_session(args)
        undo.callback(session.close)
        try:
            server = foxglove.start_server(
                name=f"lessmap {args.fleet}",
                host=args.host,
                port=args.port,
                context=live.context,
                server_listener=joiners,
            )
        except Exception as exc:  # foxglove raises its own error kinds for a taken port
            msg = f"cannot serve on {args.host}:{args.port} (choose another with --port): {exc}"
            raise ConfigError(msg) from exc
        undo.callback(server.stop)
        port = server.port  # 0 once stopped
        log.info(
            "Foxglove WebSocket server on ws://%s:%d (open it in Foxglove or Lichtblick)",
            args.host,
            port,
        )
        if record is not None:
            undo.callback(_open_mcap(args.mcap, record.context, overwrite=False).close)
        counts = _follow(args, stop, session, live=live, record=record, joiners=joiners)
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
    if args.mcap.exists() and not args.overwrite:
        msg = f"{args.mcap} exists (give --overwrite to replace it)"
        raise ConfigError(msg)
    with ExitStack() as undo:
        session = _open_session(args)
        undo.callback(session.close)
        undo.callback(_open_mcap(args.mcap, record.context, overwrite=args.overwrite).close)
        counts = _follow(args, stop, session, record=record)
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


def _open_session(args: argparse.Namespace) -> zenoh.Session:
    """Open the session of view or record, saying so once if the router keeps it waiting."""
    net = zenoh_options(args)
    try:
        return net.open_session(timeout_s=min(ANNOUNCE_WAIT_S, net.connect_timeout_s))
    except ConnectionError:
        if net.connect_timeout_s <= ANNOUNCE_WAIT_S:
            raise
    log.info(
        "waiting for the lessmap service on %s (up to %g s, --connect-timeout)",
        net.where,
        net.connect_timeout_s,
    )
    return net.open_session(timeout_s=net.connect_timeout_s - ANNOUNCE_WAIT_S)


def _follow(
    args: argparse.Namespace,
    stop: StopSignal,
    session: zenoh.Session,
    *,
    live: Channels | None = None,
    record: Channels | None = None,
    joiners: LateJoiners | None = None,
) -> dict[str, int]:
    """Feed the channels from the fleet until a signal or --duration (the caller closes)."""
    from lessmap.viz.feed import FleetFeed
    from lessmap_client.connection import Connection

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

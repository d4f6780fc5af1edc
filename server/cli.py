"""``daylit serve`` and ``daylit calibrate`` (registered by ``daylit/cli.py``)."""

from __future__ import annotations

import argparse
import asyncio
import errno
import logging
import os
import signal
import socket
import sys
import time

SERVE_EPILOG = """\
sky sources:
  sim                   the built-in simulated sky over the site (default): true sun
                        position for the manifest's latitude, longitude and time zone,
                        drifting clouds; its clock starts in daylight at the site
                        and runs 20 times faster (--set sim.start=now --set
                        sim.clock_speed=1: the real sky of the moment)
  replay:PATH           a folder of images (in name order) or a video file, looping
  camera:INDEX_OR_URL   a live camera: device index (camera:0), file, or stream URL
                        (camera:rtsp://...); reconnects on its own when it stops

examples:
  daylit serve build/demo
  daylit serve build/asuka --sky camera:0 --config site.toml
  daylit serve build/demo --set sim.start=2026-06-21T06:00 --set sim.clock_speed=120

Settings come from defaults, then --config FILE (TOML), then flags; docs/server.md lists
every key. Logs go to standard error.
"""


# After SIGTERM or Ctrl-C: the light stream's clients are closed with 1001 first (at most
# 2 s, server.app.CLOSE_CLIENTS_S), then aiohttp waits at most this long for other requests.
SHUTDOWN_TIMEOUT_S = 2.0


def add_subcommands(subparsers) -> None:
    serve = subparsers.add_parser(
        "serve",
        help="measure the sky and stream it to every visitor; serve the web client",
        description=(
            "Serve a baked site: measure the sky from a fisheye camera (or the simulated sky), "
            "stream the light vector over WebSockets (GET /ws/light) and serve the web "
            "client, three.js and the build. Runs until interrupted."
        ),
        epilog=SERVE_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    serve.add_argument("build", metavar="BUILD", help="build directory with manifest.json")
    serve.add_argument("--host", help="address to listen on (default 0.0.0.0: all)")
    serve.add_argument("--port", type=int, help="TCP port (default 8000)")
    serve.add_argument("--sky", metavar="SPEC",
                       help="sky source: sim | replay:PATH | camera:INDEX_OR_URL (default sim)")
    serve.add_argument("--site-camera", metavar="SPEC",
                       help="kiosk site camera: camera:INDEX_OR_URL | replay:PATH (default none)")
    serve.add_argument("--config", metavar="FILE", help="TOML settings file")
    serve.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                       help="override one setting, e.g. --set stream.smoothing_s=5 (repeatable)")
    serve.add_argument("--log-level", default="info",
                       choices=["debug", "info", "warning", "error"], help="default: info")
    serve.set_defaults(run=run_serve)

    from server.calibrate import add_calibrate_parser

    add_calibrate_parser(subparsers)


def setup_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%Y-%m-%d %H:%M:%S",
        stream=sys.stderr,
    )
    logging.getLogger("aiohttp.access").setLevel(logging.WARNING)
    if level != "debug":
        # OpenCV repeats every failed camera open on stderr; our own log lines say it once.
        import cv2

        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def _lan_address() -> str | None:
    """This machine's address as others on the network would use it (no traffic sent)."""
    try:
        address = socket.gethostbyname(socket.gethostname())
    except OSError:
        return None
    return None if address.startswith("127.") else address


def _raise_open_file_limit(wanted: int, log: logging.Logger) -> None:
    """Each client is a socket: lift the soft limit on open files toward the hard limit."""
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        target = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
        if soft != resource.RLIM_INFINITY and soft < target:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        if soft != resource.RLIM_INFINITY and soft < wanted:
            log.warning("only %d open files allowed (ulimit -n): fewer clients than "
                        "max_clients may connect", soft)
    except (ImportError, ValueError, OSError):
        pass


def run_serve(args: argparse.Namespace) -> int:
    from daylit.manifest import ManifestError
    from server.config import ConfigError, load_settings, parse_override
    from server.fisheye import CalibrationError

    setup_logging(args.log_level)
    log = logging.getLogger("daylit.server")
    try:
        overrides = dict(parse_override(text) for text in args.set)
        for flag, key in (("host", "server.host"), ("port", "server.port"),
                          ("sky", "sky.source"), ("site_camera", "site_camera.source")):
            if getattr(args, flag) is not None:
                overrides[key] = getattr(args, flag)
        settings = load_settings(args.config, overrides)
        from server.app import create_app

        app = create_app(args.build, settings)
    except (ConfigError, ManifestError, CalibrationError) as exc:
        print(f"daylit serve: error: {exc}", file=sys.stderr)
        return 2
    _raise_open_file_limit(settings.server.max_clients + 256, log)
    try:
        return asyncio.run(_serve(app, settings, log))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            print(f"daylit serve: error: port {settings.server.port} on "
                  f"{settings.server.host} is already in use (another daylit serve?); "
                  "choose another with --port", file=sys.stderr)
            return 1
        if exc.errno in (errno.EACCES, errno.EADDRNOTAVAIL):
            print(f"daylit serve: error: cannot listen on {settings.server.host}:"
                  f"{settings.server.port}: {exc.strerror}", file=sys.stderr)
            return 1
        raise


async def _serve(app, settings, log) -> int:
    from aiohttp import web

    from server.app import MANIFEST, OCCLUSION, PIPELINE, relearn_occlusion
    from server.connections import GuardedSite

    host, port = settings.server.host, settings.server.port
    # keepalive_timeout is also how long a new connection may take to send its headers.
    runner = web.AppRunner(app, handle_signals=False, access_log=None,
                           keepalive_timeout=settings.server.header_timeout_s,
                           shutdown_timeout=SHUTDOWN_TIMEOUT_S)
    await runner.setup()
    site = GuardedSite(runner, host, port,
                       max_connections_per_address=settings.server.max_connections_per_address)
    try:
        await site.start()
    except OSError:
        await runner.cleanup()
        raise
    scene = app[MANIFEST]["scene"]
    shown = "localhost" if host in ("0.0.0.0", "::", "") else host
    print(f"daylit: serving {scene['name']} ({scene['id']}, {app[MANIFEST]['dome']['count']} "
          f"lights), sky: {app[PIPELINE].source.name}", flush=True)
    sim = getattr(app[PIPELINE].source, "sim", None)
    if sim is not None:
        import datetime as dt
        from zoneinfo import ZoneInfo

        start = dt.datetime.fromtimestamp(sim.clock.start_s, ZoneInfo(sim.timezone))
        print(f"daylit: simulated sky from {start:%Y-%m-%d %H:%M} local time at the site, "
              f"{sim.clock.speed:g} times real time"
              + (" (always by day)" if sim.keep_daylight else ""), flush=True)
    print(f"daylit: open http://{shown}:{port}/", flush=True)
    lan = _lan_address() if host in ("0.0.0.0", "::", "") else None
    if lan:
        print(f"daylit: on the site network: http://{lan}:{port}/", flush=True)
    print(f"daylit: status: http://{shown}:{port}/api/status  (Ctrl-C to stop)", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    if app[OCCLUSION] is not None:
        view = app[OCCLUSION].config.view_id
        print(f"daylit: occlusion by visitors on the site camera (view {view!r}); "
              f"kill -HUP {os.getpid()} re-learns the empty site", flush=True)

    def hangup() -> None:
        log.info("SIGHUP")
        relearn_occlusion(app)

    loop.add_signal_handler(signal.SIGHUP, hangup)
    started = time.monotonic()
    try:
        await stop.wait()
    finally:
        log.info("stopping after %.0f s", time.monotonic() - started)
        await runner.cleanup()
    return 0

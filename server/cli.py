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
  scene                 no sky camera: the sun and sky estimated from the site camera's
                        frames of the build's fixed view (needs --site-camera; [scene])

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
                       help="sky source: sim | scene | replay:PATH | camera:INDEX_OR_URL "
                       "(default sim)")
    serve.add_argument("--site-camera", metavar="SPEC",
                       help="kiosk site camera: camera:INDEX_OR_URL | replay:PATH (default none)")
    serve.add_argument("--config", metavar="FILE", help="TOML settings file")
    serve.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                       help="override one setting, e.g. --set stream.smoothing_s=5 (repeatable)")
    serve.add_argument("--workers", type=int, metavar="N",
                       help="fan-out processes holding the clients on the one port, fed by "
                            "one measuring process (default 1: one process does everything)")
    serve.add_argument("--broker", metavar="URL",
                       help="redis://HOST:PORT/DB: measuring and fan-out processes on several "
                            "machines share this Redis (docs/server.md)")
    serve.add_argument("--role", choices=["all", "measure", "fanout"],
                       help="with --broker: measure (the measuring process alone) or fanout "
                            "(fan-out workers alone); default all")
    serve.add_argument("--tls-cert", metavar="FILE",
                       help="serve HTTPS and WSS with this PEM certificate (chain); with "
                            "--tls-key (docs/server.md, HTTPS)")
    serve.add_argument("--tls-key", metavar="FILE", help="the PEM private key of --tls-cert")
    serve.add_argument("--allow-host", metavar="NAME", action="append", default=None,
                       help="a Host name this server answers for (its domain behind a proxy; "
                            "*.example.org for a domain); repeatable. IP addresses, localhost "
                            "and the machine's names are always allowed")
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
    """This machine's address as others on the network would use it (no traffic sent): the
    source address of a route out (a UDP socket's connect sends nothing), else the host name's
    address (Debian maps the host name to 127.0.1.1, hence the route first)."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.connect(("192.0.2.1", 9))  # TEST-NET-1: never answered, never sent to
            address = probe.getsockname()[0]
        if not address.startswith(("127.", "0.")):
            return address
    except OSError:
        pass
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
                          ("sky", "sky.source"), ("site_camera", "site_camera.source"),
                          ("workers", "server.workers"), ("broker", "server.broker"),
                          ("role", "server.role"), ("tls_cert", "server.tls_cert"),
                          ("tls_key", "server.tls_key")):
            if getattr(args, flag) is not None:
                overrides[key] = getattr(args, flag)
        if args.allow_host:
            overrides["access.allowed_hosts"] = list(args.allow_host)
        settings = load_settings(args.config, overrides)
        srv = settings.server
        tls = None
        if srv.tls_cert:
            from server.tls import server_context

            tls = server_context(srv.tls_cert, srv.tls_key)
        split = srv.role != "all" or srv.workers > 1 or bool(srv.broker)
        if split:
            _tag_log(srv.role)
        if srv.role == "fanout":
            from server.fanout import create_fanout_app

            link = _subscriber(srv.broker, args.build)
            app = create_fanout_app(args.build, settings, link, _link_name(srv.broker))
        else:
            from server.app import create_app

            app = create_app(args.build, settings)
    except (ConfigError, ManifestError, CalibrationError) as exc:
        print(f"daylit serve: error: {exc}", file=sys.stderr)
        return 2
    _raise_open_file_limit(settings.server.max_clients + 256, log)
    try:
        if srv.role == "fanout" and srv.workers > 1:
            return asyncio.run(_serve_pool(args, settings, None))
        if srv.role == "fanout":
            return asyncio.run(_serve_fanout(app, settings, link, log, tls))
        if split:
            return asyncio.run(_serve_pool(args, settings, app))
        return asyncio.run(_serve(app, settings, log, tls=tls))
    except LinkError as exc:
        print(f"daylit serve: error: {exc}", file=sys.stderr)
        return 1
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


def _ignore_further_stops(loop) -> None:
    """Stopping: a second SIGTERM (systemd and ``timeout`` signal a whole process group, the
    parent forwards one more) must not land while the event loop closes its wake-up fd."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.remove_signal_handler(sig)
        signal.signal(sig, signal.SIG_IGN)


class LinkError(RuntimeError):
    """The broker or the measuring process's feed cannot be reached at start."""


def _tag_log(role: str) -> None:
    """Log lines of several processes on one stderr: say which process wrote each."""
    from server.workers import WORKER_ENV

    number = os.environ.get(WORKER_ENV)
    tag = f"worker {number}" if number else ("measuring" if role != "fanout" else "fanout")
    for handler in logging.getLogger().handlers:
        handler.setFormatter(logging.Formatter(
            f"%(asctime)s %(levelname)-7s [{tag} %(process)d] %(name)s: %(message)s",
            "%Y-%m-%d %H:%M:%S"))


def _link_name(broker: str) -> str:
    from server.broker import redacted

    return redacted(broker)


def _scene_id(build) -> str:
    from daylit import manifest as manifest_io

    return manifest_io.load(build)["scene"]["id"]


def _subscriber(broker: str, build):
    if broker.startswith("local:"):
        from server.localfeed import LocalFeedSubscriber

        return LocalFeedSubscriber(broker)
    from server.broker import RedisSubscriber

    return RedisSubscriber(broker, _scene_id(build))


def _stop_event(log) -> asyncio.Event:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()

    def stopping(name: str) -> None:
        log.info("%s", name)
        stop.set()
        _ignore_further_stops(loop)

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stopping, sig.name)
    return stop


async def _serve_fanout(app, settings, link, log, tls=None) -> int:
    """One fan-out worker: check its link, then serve with SO_REUSEPORT."""
    from server.broker import BrokerError
    from server.localfeed import FeedError
    from server.workers import die_with_parent

    die_with_parent()
    try:
        await link.check()
    except (BrokerError, FeedError) as exc:
        raise LinkError(str(exc)) from None
    return await _serve(app, settings, log, reuse_port=True, tls=tls)


async def _serve_pool(args, settings, app) -> int:
    """The measuring process (``app``; None: fan-out workers only) and its fan-out workers."""
    from server.broker import BrokerError, RedisPublisher
    from server.localfeed import FeedError, LocalFeedPublisher
    from server.relay import Outbox
    from server.workers import WorkerPool, local_feed_url, serve_measuring, worker_argv

    log = logging.getLogger("daylit.workers")
    srv = settings.server
    broker, folder = srv.broker, None
    if not broker:
        broker, folder = local_feed_url()
    stop = _stop_event(log)
    workers = srv.workers if srv.role != "measure" else 0
    pool = WorkerPool(workers, worker_argv(args, settings, broker)) if workers else None
    try:
        if app is None:  # --role fanout --workers N: the workers alone
            try:
                await _subscriber(broker, args.build).check()
            except (BrokerError, FeedError) as exc:
                raise LinkError(str(exc)) from None
            await pool.start()
            ok = await pool.wait_ready()
            if ok:
                print(f"daylit: {workers} fan-out workers on port {srv.port}, fed by "
                      f"{_link_name(broker)}", flush=True)
                shown = "localhost" if srv.host in ("0.0.0.0", "::", "") else srv.host
                scheme = "https" if srv.tls_cert else "http"
                print(f"daylit: open {scheme}://{shown}:{srv.port}/", flush=True)
                failed = asyncio.ensure_future(pool.failed.wait())
                stopped = asyncio.ensure_future(stop.wait())
                await asyncio.wait({failed, stopped}, return_when=asyncio.FIRST_COMPLETED)
                failed.cancel()
                stopped.cancel()
                ok = not pool.failed.is_set()
            await pool.stop()
            return 0 if ok else 1
        outbox = Outbox()
        if broker.startswith("local:"):
            link = LocalFeedPublisher(broker, outbox)
        else:
            link = RedisPublisher(broker, _scene_id(args.build), outbox)
        try:
            await link.start()
        except (BrokerError, FeedError) as exc:
            raise LinkError(str(exc)) from None
        return await serve_measuring(app, settings, link, pool, stop)
    finally:
        if folder is not None:
            import shutil

            shutil.rmtree(folder, ignore_errors=True)


def _banner(app) -> None:
    from server.app import MANIFEST, PIPELINE

    scene = app[MANIFEST]["scene"]
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


async def _serve(app, settings, log, reuse_port: bool = False, tls=None) -> int:
    from aiohttp import web

    from server.app import OCCLUSION, PIPELINE, relearn_occlusion
    from server.connections import GuardedSite

    host, port = settings.server.host, settings.server.port
    # keepalive_timeout is also how long a new connection may take to send its headers.
    runner = web.AppRunner(app, handle_signals=False, access_log=None,
                           keepalive_timeout=settings.server.header_timeout_s,
                           shutdown_timeout=SHUTDOWN_TIMEOUT_S)
    await runner.setup()
    site = GuardedSite(runner, host, port,
                       max_connections_per_address=settings.server.max_connections_per_address,
                       reuse_port=reuse_port, ssl_context=tls)
    try:
        await site.start()
    except OSError:
        await runner.cleanup()
        raise
    shown = "localhost" if host in ("0.0.0.0", "::", "") else host
    if PIPELINE in app:
        _banner(app)
    else:
        from server.fanout import LINK_NAME

        print(f"daylit: fan-out worker (pid {os.getpid()}), fed by {app[LINK_NAME]}",
              flush=True)
    scheme = "https" if tls is not None else "http"
    print(f"daylit: open {scheme}://{shown}:{port}/", flush=True)
    lan = _lan_address() if host in ("0.0.0.0", "::", "") else None
    if lan:
        print(f"daylit: on the site network: {scheme}://{lan}:{port}/", flush=True)
        if tls is None:
            print("daylit: phones allow the camera and AR over HTTPS only: serve with "
                  "--tls-cert FILE --tls-key FILE (docs/server.md, \"A phone on the same "
                  "network\")", flush=True)
    print(f"daylit: status: {scheme}://{shown}:{port}/api/status  (operators; Ctrl-C to "
          "stop)", flush=True)
    from server.access import AccessPolicy

    if AccessPolicy.from_settings(settings).token:
        print(f"daylit: kiosk: {scheme}://{shown}:{port}/?mode=kiosk&token=<the operator token>"
              " (also for /api/status)", flush=True)
    else:
        print(f"daylit: kiosk: {scheme}://localhost:{port}/?mode=kiosk on this machine only; "
              "elsewhere set DAYLIT_OPERATOR_TOKEN (docs/server.md, Who can see what)",
              flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    if OCCLUSION in app and app[OCCLUSION] is not None:
        view = app[OCCLUSION].config.view_id
        print(f"daylit: occlusion by visitors on the site camera (view {view!r}); "
              f"kill -HUP {os.getpid()} re-learns the empty site", flush=True)

    def hangup() -> None:
        log.info("SIGHUP")
        if OCCLUSION in app:
            relearn_occlusion(app)

    loop.add_signal_handler(signal.SIGHUP, hangup)
    started = time.monotonic()
    try:
        await stop.wait()
        _ignore_further_stops(loop)
    finally:
        log.info("stopping after %.0f s", time.monotonic() - started)
        await runner.cleanup()
    return 0

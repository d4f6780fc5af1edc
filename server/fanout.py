"""The application of a fan-out worker: WebSocket clients fed by a measuring process.

A fan-out worker (``daylit serve BUILD --role fanout --broker URL``, or one of the children of
``daylit serve BUILD --workers N``) has no sky source, meter or site camera: it reads the
build's manifest, serves the same routes as the single process, and publishes to its clients
what the relay (:mod:`server.relay`) brings, byte for byte. Its ``/api/status`` is the
measuring process's, as last relayed, with ``clients`` and the like its own, and ``relay``: its
link (connected, age of the last message, stale). ``stale`` and ``connected`` at the top are
false/true only when both the measuring process and the link say so. When the link has been
silent past the stale time (a broker or measuring process gone), the worker re-sends its last
vector to its clients marked STALE (:meth:`server.relay.Inbox.mark_stale_if_lost`), so they
show the light as stale at once rather than after their own time-out.
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from pathlib import Path

from aiohttp import web

from daylit import __version__
from daylit import manifest as manifest_io
from server import protocol
from server.access import AccessPolicy
from server.app import Supervisor
from server.config import Settings
from server.lightstream import LightHub
from server.relay import STATUS_PERIOD_S, Inbox
from server.routes import add_client_routes

log = logging.getLogger("daylit.server")

FIRST_STATUS_WAIT_S = 10.0
HUB = web.AppKey("fanout_hub", LightHub)
INBOX = web.AppKey("fanout_inbox", Inbox)
MANIFEST = web.AppKey("fanout_manifest", dict)
SUPERVISOR = web.AppKey("fanout_supervisor", Supervisor)
LINK = web.AppKey("fanout_link", object)  # LocalFeedSubscriber or RedisSubscriber
LINK_NAME = web.AppKey("fanout_link_name", str)
STARTED_S = web.AppKey("fanout_started_s", float)


def create_fanout_app(build_dir: Path | str, settings: Settings, link, link_name: str
                      ) -> web.Application:
    """The application of one fan-out worker; ``link`` has ``run(inbox)`` (a subscriber of
    :mod:`server.localfeed` or :mod:`server.broker`), ``link_name`` says what it is."""
    build_dir = Path(build_dir)
    manifest = manifest_io.load(build_dir)
    scene = manifest["scene"]
    stream = settings.stream
    srv = settings.server
    inbox: Inbox | None = None

    def hello(streams: list[str], version: int = protocol.PROTOCOL_VERSION) -> str:
        info = inbox.hello if inbox is not None else {}
        return protocol.hello_message(
            scene_id=scene["id"],
            light_count=manifest["dome"]["count"],
            manifest_url="/build/manifest.json",
            source=info.get("source", "unknown (no word from the measuring process yet)"),
            simulated=bool(info.get("simulated", False)),
            streams=streams,
            site_camera=info.get("site_camera"),
            smoothing_s=stream.smoothing_s,
            server_time_s=time.time(),
            extra={"server": f"daylit {__version__}", "asset_query": "v",
                   "views": [v["id"] for v in manifest["views"]]},
            occlusion=info.get("occlusion"),
            version=version,
        )

    hub = LightHub(
        hello,
        max_clients=srv.max_clients,
        allowed_origins=srv.allowed_origins,
        slow_client_timeout_s=srv.slow_client_timeout_s,
        client_max_messages_per_s=srv.client_max_messages_per_s,
        heartbeat_s=srv.heartbeat_s,
    )
    # The status comes every STATUS_PERIOD_S: a few missed is a link or a process down.
    inbox = Inbox(hub, max(settings.sky.stale_after_s, 3 * STATUS_PERIOD_S))

    app = web.Application()
    app[HUB] = hub
    app[INBOX] = inbox
    app[MANIFEST] = manifest
    app[LINK] = link
    app[LINK_NAME] = link_name
    app[STARTED_S] = time.time()
    app[SUPERVISOR] = Supervisor(0.05, 2.0)
    app.cleanup_ctx.append(_background)
    app.on_shutdown.append(_close_streams)
    add_client_routes(app, hub, status, sky_jpeg, Path(srv.web_root), Path(srv.three_root),
                      build_dir, manifest,
                      AccessPolicy.from_settings(settings))
    return app


async def _background(app: web.Application):
    app[SUPERVISOR].start("relay", lambda: app[LINK].run(app[INBOX]))
    app[SUPERVISOR].start("stale link watchdog", app[INBOX].watch_link)
    try:  # before listening: so the first clients' hello names the sources
        await asyncio.wait_for(app[INBOX].has_status.wait(), FIRST_STATUS_WAIT_S)
    except TimeoutError:
        log.warning("no word from the measuring process in %.0f s (is it running?); serving "
                    "anyway, the light follows when it comes", FIRST_STATUS_WAIT_S)
    yield
    await app[SUPERVISOR].stop()
    await app[HUB].close_all()


async def _close_streams(app: web.Application) -> None:
    await asyncio.gather(app[HUB].close_all(), app[SUPERVISOR].stop())


def status_body(app: web.Application) -> dict:
    """The worker's ``/api/status`` (module docstring)."""
    inbox = app[INBOX]
    hub = app[HUB]
    measuring = inbox.status
    link = {"role": "fanout", "pid": os.getpid(), "link": app[LINK_NAME],
            **inbox.link_status()}
    return {
        **measuring,
        **hub.status(),
        "stale": bool(measuring.get("stale", True)) or inbox.stale,
        "connected": bool(measuring.get("connected", False)) and inbox.connected
        and not inbox.stale,
        "sequence": hub.sequence["light"],
        "scene": app[MANIFEST]["scene"]["id"],
        "lights": app[MANIFEST]["dome"]["count"],
        "uptime_s": round(time.time() - app[STARTED_S], 1),
        "server_time_s": time.time(),
        "restarts": app[SUPERVISOR].restarts,
        "relay": link,
        "measuring_relay": measuring.get("relay"),
        "measuring_uptime_s": measuring.get("uptime_s"),
    }


async def status(request: web.Request) -> web.Response:
    """``GET /api/status`` of a worker."""
    resp = web.json_response(status_body(request.app), headers={"Cache-Control": "no-store"})
    resp.enable_compression()
    return resp


async def sky_jpeg(request: web.Request) -> web.Response:
    """``GET /api/sky.jpg``: the measuring process's newest sky frame as relayed (at most
    320 px, whatever ``?size=`` asks)."""
    data = request.app[INBOX].sky_jpeg
    if data is None:
        raise web.HTTPServiceUnavailable(text="no sky frame yet\n", headers={"Retry-After": "1"})
    return web.Response(body=data, content_type="image/jpeg",
                        headers={"Cache-Control": "no-store"})

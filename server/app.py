"""The aiohttp application of ``daylit serve``: factory, shared state and background tasks.

:func:`create_app` reads the build's manifest (the dome comes from there, never from the
baker), builds the measuring chain from the settings and registers the routes. Its
``cleanup_ctx`` runs the background tasks under a supervisor that logs and restarts any that
fail, with a pause that doubles up to 30 s, so the server keeps going for days:

- the sky source (sim, replay or camera) -> ``LightPipeline.deliver``; with ``scene``, the
  site camera's frames go there too (:mod:`server.sources.scene`, :mod:`server.scenemeter`);
- measuring (newest frame -> vector -> hub), and the stale-light watchdog;
- the site camera, when configured, with occlusion by visitors on its frames
  (:mod:`server.occlusionfeed`: a worker process, started with the site camera), and beside a
  sky camera the scene estimate of its frames (:mod:`server.fusion`: the sun where the sky
  camera clips it, and the two sources' disagreement).

When the server stops (SIGTERM, Ctrl-C), ``on_shutdown`` closes every light stream with 1001
and stops the background tasks before aiohttp closes the remaining connections, so the
process exits within a few seconds and no client sees 1006.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import cv2
import numpy as np
from aiohttp import web

from daylit import __version__
from daylit import manifest as manifest_io
from daylit.sun import SunPath
from server import protocol, sunbouncedates
from server.access import AccessPolicy
from server.backoff import Backoff
from server.config import ConfigError, Settings, SourceSpec, load_settings
from server.fisheye import FisheyeCamera, load_calibration
from server.fusion import SceneFusion
from server.lightstream import LightHub
from server.measure import SkyMeter
from server.occlusionfeed import OcclusionConfig, OcclusionRunner
from server.photometry import Photometry, inverse_response_table
from server.pipeline import LightPipeline
from server.routes import add_client_routes
from server.sceneestimate import SceneEstimateError
from server.scenemeter import SceneMeter, scene_meter_for_build
from server.simsky import SimulatedSky
from server.sitecamera import SiteCameraFeed
from server.sources import CameraSource, ReplaySource, SceneFrames, SimSource, Source
from server.sunmeter import SunMeter
from server.temporalfilter import TemporalFilter

log = logging.getLogger("daylit.server")

SETTINGS = web.AppKey("settings", Settings)
MANIFEST = web.AppKey("manifest", dict)
HUB = web.AppKey("hub", LightHub)
PIPELINE = web.AppKey("pipeline", LightPipeline)
SITE_CAMERA = web.AppKey("site_camera", object)  # SiteCameraFeed or None
OCCLUSION = web.AppKey("occlusion", object)  # OcclusionRunner or None
OCCLUSION_OFF = web.AppKey("occlusion_off", str)  # why there is no occlusion ("" if there is)
SUPERVISOR = web.AppKey("supervisor", object)


class Supervisor:
    """Runs named background coroutines forever, restarting any that end or fail."""

    def __init__(self, min_backoff_s: float = 1.0, max_backoff_s: float = 30.0):
        self.min_backoff_s = min_backoff_s
        self.max_backoff_s = max_backoff_s
        self.tasks: dict[str, asyncio.Task] = {}
        self.restarts: dict[str, int] = {}

    def start(self, name: str, factory: Callable[[], Awaitable[None]]) -> None:
        self.restarts[name] = 0
        self.tasks[name] = asyncio.create_task(self._keep(name, factory), name=name)

    async def _keep(self, name: str, factory) -> None:
        backoff = Backoff(self.min_backoff_s, self.max_backoff_s)
        while True:
            started = time.monotonic()
            try:
                await factory()
                log.warning("%s ended; restarting in %.0f s", name, backoff.delay_s)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                log.error("%s failed: %s; restarting in %.0f s", name, exc, backoff.delay_s,
                          exc_info=not isinstance(exc, OSError | ValueError | RuntimeError))
            if time.monotonic() - started > 60.0:
                backoff.reset()  # it ran well for a while: start over
            self.restarts[name] += 1
            await backoff.wait()

    async def stop(self) -> None:
        for task in self.tasks.values():
            task.cancel()
        await asyncio.gather(*self.tasks.values(), return_exceptions=True)
        self.tasks.clear()


def make_sky_source(spec: SourceSpec, settings: Settings, scene: dict) -> Source:
    sky = settings.sky
    if spec.kind == "sim":
        sim = settings.sim
        simulated = SimulatedSky.for_site(
            scene["latitude_deg"], scene["longitude_deg"], scene["elevation_m"],
            scene["timezone"], cloud_cover=sim.cloud_cover, clock_speed=sim.clock_speed,
            start=sim.start, seed=sim.seed, noise=sim.noise, size_px=sim.size_px,
        )
        simulated.linke_turbidity = settings.sun.linke_turbidity
        return SimSource(simulated, sky.rate_hz)
    if spec.kind == "replay":  # brackets in it are merged with the sky camera's response
        return ReplaySource(spec.target, sky.rate_hz, make_photometry(settings))
    return CameraSource(spec.camera_target, sky.rate_hz, sky.reconnect_min_s,
                        sky.reconnect_max_s)


def make_scene_meter(settings: Settings, manifest: dict, build_dir: Path) -> SceneMeter:
    """The meter that estimates the sun and sky from the site camera's frames
    (:mod:`server.scenemeter`, ``[scene]`` settings); :class:`SceneEstimateError` or
    ``ValueError`` when the build or the settings cannot support one."""
    cfg = settings.scene
    site = manifest["scene"]
    inverse_response_table(cfg.response)
    return scene_meter_for_build(
        build_dir, manifest, cfg.view,
        SunPath(site["latitude_deg"], site["longitude_deg"], site["elevation_m"],
                settings.sun.linke_turbidity),
        cfg.samples, response=cfg.response, radiance_per_unit=cfg.radiance_per_unit,
        photometric_factor=tuple(cfg.photometric_factor),
        saturation_level=settings.sky.saturation_level)


def make_scene_source(settings: Settings, manifest: dict, build_dir: Path,
                      site_source: Source | None) -> SceneFrames:
    """``[sky] source = "scene"``: the site camera's frames and the meter that estimates the
    sun and sky from them (:mod:`server.scenemeter`)."""
    if site_source is None:
        raise ConfigError("[sky] source = scene needs a site camera ([site_camera] source or "
                          "--site-camera)")
    try:
        meter = make_scene_meter(settings, manifest, build_dir)
    except (SceneEstimateError, ValueError) as exc:
        raise ConfigError(f"[sky] source = scene: {exc}") from None
    return SceneFrames(site_source, meter)


def make_fusion(settings: Settings, manifest: dict, build_dir: Path, sky_kind: str,
                has_site_camera: bool) -> tuple[SceneFusion | None, str]:
    """The scene estimate beside a sky camera (``[sky] fuse_scene``), or None and why not."""
    if not settings.sky.fuse_scene:
        return None, "[sky] fuse_scene = false"
    if sky_kind not in ("camera", "replay"):
        return None, f"the sky source is {sky_kind}, not a sky camera"
    if not has_site_camera:
        return None, "no site camera"
    try:
        meter = make_scene_meter(settings, manifest, build_dir)
    except SceneEstimateError as exc:  # e.g. no fixed view: the sky camera alone, as before
        log.warning("no scene estimate beside the sky camera: %s", exc)
        return None, str(exc)
    except ValueError as exc:
        raise ConfigError(f"[scene]: {exc}") from None
    return SceneFusion(meter, manifest_io.dome_vertices(manifest),
                       settings.scene.disagreement_factor, settings.sky.stale_after_s,
                       settings.sky.rate_hz, settings.scene.drift_factor), ""


def make_site_source(spec: SourceSpec, settings: Settings) -> Source:
    cam = settings.site_camera
    if spec.kind == "replay":
        source = ReplaySource(spec.target, cam.rate_hz)
    else:
        source = CameraSource(spec.camera_target, cam.rate_hz, settings.sky.reconnect_min_s,
                              settings.sky.reconnect_max_s)
    source.name = f"site {source.name}"
    return source


def make_photometry(settings: Settings) -> Photometry:
    sky = settings.sky
    response: object = sky.response
    if sky.response not in ("srgb", "linear") and not sky.response.startswith("gamma:"):
        path = Path(sky.response)
        try:
            response = json.loads(path.read_text("utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"[sky] response: cannot read table {path}: {exc}") from None
    photometry = Photometry(
        response=response,
        exposure=sky.exposure,
        photometric_factor=tuple(sky.photometric_factor),
        vignetting=tuple(sky.vignetting),
        saturation_level=sky.saturation_level,
    )
    try:
        inverse_response_table(photometry.response)
    except ValueError as exc:
        raise ConfigError(f"[sky] response: {exc}") from None
    return photometry


def make_meter(settings: Settings, manifest: dict, simulated: SimulatedSky | None) -> SkyMeter:
    sky = settings.sky
    camera: FisheyeCamera | None = None
    if sky.calibration:
        camera, _ = load_calibration(sky.calibration)
    elif simulated is not None:
        camera = simulated.camera  # the simulated lens is known exactly
    mask = None
    if sky.sky_mask:
        mask = cv2.imread(sky.sky_mask, cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise ConfigError(f"[sky] sky_mask: cannot read {sky.sky_mask}")
    photometry = make_photometry(settings)
    if simulated is not None:
        simulated.photometry = Photometry(response=photometry.response,
                                          vignetting=photometry.vignetting)
    sun = None
    if settings.sun.enabled:
        scene = manifest["scene"]
        sun = SunMeter(scene["latitude_deg"], scene["longitude_deg"], scene["elevation_m"],
                       settings.sun.linke_turbidity)
    return SkyMeter(
        manifest_io.dome_vertices(manifest),
        photometry,
        camera=camera,
        fov_deg=sky.fov_deg,
        supersample=sky.supersample,
        max_working_pixels=sky.max_working_pixels,
        sky_mask=mask,
        sun=sun,
    )


def make_occlusion(settings: Settings, manifest: dict, build_dir: Path,
                   has_site_camera: bool) -> tuple[OcclusionRunner | None, str]:
    """The occlusion runner for the site camera, or None and the reason why there is none."""
    occ = settings.occlusion
    if not has_site_camera:
        return None, "no site camera"
    if not occ.enabled:
        return None, "[occlusion] enabled = false"
    views = manifest["views"]
    if occ.view and not any(v["id"] == occ.view for v in views):
        known = ", ".join(v["id"] for v in views) or "none"
        raise ConfigError(f"[occlusion] view {occ.view!r} is not a view of the build "
                          f"(views: {known})")
    if not views:
        log.warning("occlusion off: the build has no fixed view for the site camera (bake the "
                    "scene with a [[view]])")
        return None, "the build has no fixed view"
    try:
        inverse_response_table(occ.response)
    except ValueError as exc:
        raise ConfigError(f"[occlusion] response: {exc}") from None
    view = next(v for v in views if v["id"] == occ.view) if occ.view else views[0]
    config = OcclusionConfig(
        build_dir=str(build_dir), view_id=view["id"],
        view_size=(int(view["width"]), int(view["height"])), max_width=occ.max_width,
        learn_frames=occ.learn_frames, response=occ.response,
    )
    return OcclusionRunner(config, occ.worker), ""


def create_app(
    build_dir: Path | str,
    settings: Settings | None = None,
    sky_source: Source | None = None,
    site_source: Source | None = None,
    meter: SkyMeter | None = None,
) -> web.Application:
    """The application for one build.

    ``sky_source``, ``site_source`` and ``meter`` replace what the settings describe (tests
    use them to inject a controllable source).
    """
    build_dir = Path(build_dir)
    settings = settings or load_settings()
    manifest = manifest_io.load(build_dir)
    if (late := sunbouncedates.warning(manifest, time.time())) is not None:
        log.warning(late)
    scene = manifest["scene"]
    if site_source is None and settings.site_camera.source is not None:
        site_source = make_site_source(settings.site_camera.source, settings)
    scene_frames: SceneFrames | None = None
    if sky_source is None and settings.sky.source.kind == "scene":
        scene_frames = make_scene_source(settings, manifest, build_dir, site_source)
        sky_source = scene_frames
        meter = meter or scene_frames.meter
    fusion: SceneFusion | None = None
    fusion_off = "the sky source was given to create_app"
    if sky_source is None:
        sky_source = make_sky_source(settings.sky.source, settings, scene)
        fusion, fusion_off = make_fusion(settings, manifest, build_dir,
                                         settings.sky.source.kind, site_source is not None)
    simulated = sky_source.sim if isinstance(sky_source, SimSource) else None
    meter = meter or make_meter(settings, manifest, simulated)

    occlusion, occlusion_off = make_occlusion(settings, manifest, build_dir,
                                              site_source is not None)
    light_count = manifest["dome"]["count"]
    stream = settings.stream
    site_feed: SiteCameraFeed | None = None

    def hello(streams: list[str], version: int = protocol.PROTOCOL_VERSION) -> str:
        site = None
        if site_feed is not None:
            site = {"source": site_feed.source.name, "size": site_feed.size}
        occ = None
        if occlusion is not None:
            occ = {"view": occlusion.config.view_id,
                   "size": list(occlusion.size) if occlusion.size else None}
        return protocol.hello_message(
            scene_id=scene["id"],
            light_count=light_count,
            manifest_url="/build/manifest.json",
            source=sky_source.name,
            simulated=bool(sky_source.flags & protocol.Flags.SIMULATED),
            streams=streams,
            site_camera=site,
            smoothing_s=stream.smoothing_s,
            server_time_s=time.time(),
            extra={"server": f"daylit {__version__}", "asset_query": "v",
                   "views": [v["id"] for v in manifest["views"]]},
            occlusion=occ,
            version=version,
        )

    srv = settings.server
    hub = LightHub(
        hello,
        max_clients=srv.max_clients,
        allowed_origins=srv.allowed_origins,
        slow_client_timeout_s=srv.slow_client_timeout_s,
        client_max_messages_per_s=srv.client_max_messages_per_s,
        site_camera_available=site_source is not None,
        occlusion_available=occlusion is not None,
        heartbeat_s=srv.heartbeat_s,
    )
    if site_source is not None:
        site_feed = SiteCameraFeed(site_source, hub, settings.site_camera.jpeg_quality,
                                   settings.site_camera.max_width, occlusion)
        if scene_frames is not None:
            site_feed.listeners.append(scene_frames.forward)
        if fusion is not None:
            site_feed.listeners.append(fusion.deliver)
    temporal = TemporalFilter(stream.smoothing_s, stream.change_threshold, stream.max_interval_s)
    solid_angles_sr = np.array([light["solid_angle_sr"] for light in manifest["dome"]["lights"]])
    pipeline = LightPipeline(meter, temporal, hub, sky_source, settings.sky.stale_after_s,
                             solid_angles_sr)
    pipeline.fusion, pipeline.fusion_off = fusion, fusion_off

    app = web.Application()
    app[SETTINGS] = settings
    app[MANIFEST] = manifest
    app[HUB] = hub
    app[PIPELINE] = pipeline
    app[SITE_CAMERA] = site_feed
    app[OCCLUSION] = occlusion
    app[OCCLUSION_OFF] = occlusion_off
    app[SUPERVISOR] = Supervisor(settings.sky.reconnect_min_s, settings.sky.reconnect_max_s)
    app.cleanup_ctx.append(background_tasks)
    app.on_shutdown.append(close_streams)
    add_client_routes(app, hub, status, sky_jpeg, Path(srv.web_root), Path(srv.three_root),
                      build_dir, manifest,
                      AccessPolicy.from_settings(settings))
    return app


async def background_tasks(app: web.Application):
    """``cleanup_ctx``: start the supervised tasks, and stop them (and the clients) at exit."""
    supervisor: Supervisor = app[SUPERVISOR]
    pipeline = app[PIPELINE]
    supervisor.start("sky source", pipeline.run_source)
    supervisor.start("measuring", pipeline.measure_forever)
    supervisor.start("stale watchdog", pipeline.watch_forever)
    feed = app[SITE_CAMERA]
    if feed is not None:
        supervisor.start("site camera", feed.run_source)
        supervisor.start("site camera encoder", feed.run_forever)
    if pipeline.fusion is not None:
        supervisor.start("scene estimate", pipeline.fusion.run_forever)
    yield
    await supervisor.stop()
    await app[HUB].close_all()  # already done by close_streams when the server shuts down
    if app[OCCLUSION] is not None:
        await app[OCCLUSION].close()


async def close_streams(app: web.Application) -> None:
    """``on_shutdown``: close the light streams with 1001 and stop measuring and publishing,
    before aiohttp waits for the remaining requests (a light stream would hold it 60 s)."""
    await asyncio.gather(app[HUB].close_all(), app[SUPERVISOR].stop())


def relearn_occlusion(app: web.Application) -> bool:
    """The operator's reset (SIGHUP): learn the empty site again. False if there is none."""
    runner = app[OCCLUSION]
    if runner is None:
        log.info("no occlusion to re-learn (%s)", app[OCCLUSION_OFF])
        return False
    runner.relearn()
    return True


async def status(request: web.Request) -> web.Response:
    """``GET /api/status``."""
    resp = web.json_response(status_body(request.app), headers={"Cache-Control": "no-store"})
    resp.enable_compression()
    return resp


def status_body(app: web.Application) -> dict:
    """What ``/api/status`` says (a measuring process also relays it to its workers)."""
    pipeline = app[PIPELINE]
    hub = app[HUB]
    feed = app[SITE_CAMERA]
    body = {
        **pipeline.status(),
        **hub.status(),
        "sequence": hub.sequence["light"],
        "scene": app[MANIFEST]["scene"]["id"],
        "lights": app[MANIFEST]["dome"]["count"],
        "uptime_s": round(time.time() - pipeline.started_s, 1),
        "server_time_s": time.time(),
        "restarts": app[SUPERVISOR].restarts,
        "site_camera": feed.status() if feed is not None else None,
        "occlusion": occlusion_status(app),
        "sun_bounce": sunbouncedates.coverage(app[MANIFEST], time.time()),
    }
    if pipeline.temporal.value is not None:
        body["mean_radiance"] = np.round(pipeline.temporal.value.mean(axis=0), 4).tolist()
    return body


def hello_info(app: web.Application) -> dict:
    """What a client's hello says of the sources: ``source``, ``simulated``, ``site_camera``
    and ``occlusion`` (:func:`server.protocol.hello_message`'s arguments)."""
    source = app[PIPELINE].source
    feed = app[SITE_CAMERA]
    occlusion = app[OCCLUSION]
    site = None if feed is None else {"source": feed.source.name, "size": feed.size}
    occ = None
    if occlusion is not None:
        occ = {"view": occlusion.config.view_id,
               "size": list(occlusion.size) if occlusion.size else None}
    return {"source": source.name, "simulated": bool(source.flags & protocol.Flags.SIMULATED),
            "site_camera": site, "occlusion": occ}


def occlusion_status(app: web.Application) -> dict | None:
    """``occlusion`` of ``/api/status``: None without a site camera."""
    runner = app[OCCLUSION]
    if runner is not None:
        return runner.status()
    if app[SITE_CAMERA] is None:
        return None
    return {"state": "off", "reason": app[OCCLUSION_OFF]}


async def sky_jpeg(request: web.Request) -> web.Response:
    """``GET /api/sky.jpg``: the newest sky frame, at most 320 px (``?size=`` up to 1024)."""
    try:
        size = min(1024, max(32, int(request.query.get("size", "320"))))
    except ValueError:
        raise web.HTTPBadRequest(text="size must be an integer\n") from None
    data = await asyncio.to_thread(request.app[PIPELINE].sky_jpeg, size)
    if data is None:
        raise web.HTTPServiceUnavailable(text="no sky frame yet\n",
                                         headers={"Retry-After": "1"})
    return web.Response(body=data, content_type="image/jpeg",
                        headers={"Cache-Control": "no-store"})

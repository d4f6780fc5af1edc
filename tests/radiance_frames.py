"""Frames of a small site rendered by Radiance (not daylit's tracer), through a camera model.

The site: open ground, a building, a low wall (the real proxies the estimator knows), and
optionally what it does not know: a dark person-sized box and a parked van. Radiance
(``pyradiance==1.3.1``: ``gendaylit``, ``oconv``, ``rtrace``; the helpers of
``benchmarks/radiance.py``) renders the radiance seen through each pixel of a pinhole
view, the sun and the sky apart (light adds: a cloud over the sun scales the sun's image only).
:func:`camera_frame` then makes what a camera delivers: auto-exposure, shot and read noise,
clipping, the sRGB curve, 8-bit codes, JPEG; and :func:`linearise` undoes the sRGB curve, as
the server does with the site camera's response.

Frames are the site frame's (+X east, +Y up, -Z north); Radiance's is +X east, +Y north, +Z up.
Nothing is cached between runs: every call renders.
"""

from __future__ import annotations

import math
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh

from benchmarks.radiance import (
    Sky,
    SkySpec,
    gendaylit,
    material,
    oconv,
    polygons,
    radiance_env,
    rtrace,
    sky_rad,
    sun_rad,
    to_radiance,
)
from server.sceneestimate import PinholeView

SITE = {"scene": {"latitude_deg": 34.47, "longitude_deg": 135.82, "timezone": "Asia/Tokyo"}}
GROUND_ALBEDO = (0.22, 0.20, 0.18)
BUILDING_ALBEDO = (0.55, 0.45, 0.35)
WALL_ALBEDO = (0.40, 0.42, 0.45)
PERSON_ALBEDO = (0.06, 0.05, 0.05)
VAN_ALBEDO = (0.75, 0.75, 0.78)
GROUND_HALF_M = 200.0
# Radiance settings for camera rays: two bounces, ambient cache (noise like a real image's);
# correlated sampling (-u-): the same render every run, so a test passes or fails every run --
# in one process only: with rtrace -n 2 the rays' random sequence depends on which process
# took which ray, and 61 % of a frame's pixels differed between two runs, by up to 7 %
# (uncached: a test on its goal's edge passed or failed by the run). Tests render with procs=1.
CAMERA_RAYS = ["-ab", "2", "-ad", "512", "-as", "128", "-aa", "0.15", "-ar", "64", "-lw", "1e-5",
               "-u-"]
# Without the ambient cache (-aa 0): the cache's interpolation put shaded surfaces of the
# phone's views 8-36 % too bright against Radiance's own uncached answer (shaded ground +31 %,
# a shaded north wall +21 % under the clear sky), which the estimate reads as too much sky
# (docs/web.md). Unbiased, with per-pixel noise; about 100-160 s a 320 x 180 frame here.
ACCURATE_CAMERA_RAYS = ["-ab", "2", "-ad", "256", "-aa", "0", "-lw", "1e-5", "-u-"]
SKY_IRRADIANCE = ["-ab", "1", "-aa", "0", "-ad", "8192", "-as", "0", "-lw", "1e-7", "-u-"]


def box_mesh(size_m, base_center_m) -> trimesh.Trimesh:
    """An axis-aligned box (site frame) standing on its base centre."""
    b = trimesh.creation.box(extents=size_m)
    b.apply_translation(np.asarray(base_center_m, float) + [0.0, size_m[1] / 2.0, 0.0])
    return b


def ground_mesh(half_m: float = GROUND_HALF_M) -> trimesh.Trimesh:
    h = half_m
    v = np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]], float)
    return trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)  # normal +Y


@dataclass
class KnownSite:
    """The known site: parts (name -> (mesh, albedo)) and the view."""

    parts: dict
    view: PinholeView

    def mesh_and_albedo(self, albedo_scale: dict | None = None):
        """One mesh of all parts and (F, 3) per-face albedos (optionally a part's albedo
        scaled: a wrong albedo in the model)."""
        meshes, albedo = [], []
        for name, (mesh, rho) in self.parts.items():
            meshes.append(mesh)
            s = (albedo_scale or {}).get(name, 1.0)
            albedo.append(np.tile(np.asarray(rho, float) * s, (len(mesh.faces), 1)))
        return trimesh.util.concatenate(meshes), np.vstack(albedo)


def look_at_view(eye_m, target_m, width: int, height: int, hfov_deg: float) -> PinholeView:
    """A pinhole view (OpenCV axes) from ``eye_m`` toward ``target_m``, site frame."""
    eye = np.asarray(eye_m, float)
    fwd = np.asarray(target_m, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.column_stack([right, down, fwd])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = eye
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    K = np.array([[f, 0, width / 2.0], [0, f, height / 2.0], [0, 0, 1]])
    return PinholeView(K, T, width, height)


def known_site(width: int = 320, height: int = 180) -> KnownSite:
    """Ground, an 8 x 6 x 5 m building and a 10 m wall, seen from the north, looking south
    (so the shadows they cast northward face the camera)."""
    parts = {
        "ground": (ground_mesh(), GROUND_ALBEDO),
        "building": (box_mesh((8.0, 6.0, 5.0), (0.0, 0.0, 0.0)), BUILDING_ALBEDO),
        "wall": (box_mesh((0.4, 2.0, 9.0), (-8.0, 0.0, -6.0)), WALL_ALBEDO),
    }
    view = look_at_view((3.0, 7.0, -24.0), (0.0, 0.5, -3.0), width, height, 75.0)
    return KnownSite(parts, view)


def person_mesh(position_m) -> trimesh.Trimesh:
    return box_mesh((0.5, 1.75, 0.35), position_m)


def van_mesh() -> trimesh.Trimesh:
    """A van east of the building: its shadow falls where the model expects sun."""
    return box_mesh((2.0, 2.2, 5.0), (7.5, 0.0, -6.0))


@dataclass
class RenderedSky:
    """One gendaylit sky's renders of a view: radiance images (H, W, 3) W/(m^2 sr) of the sun
    alone and the sky alone, the truth (DNI, sky horizontal irradiance; W/m^2, grey) and the
    sun's direction (site frame) at the local time."""

    sun_image: np.ndarray
    sky_image: np.ndarray
    dni_w_m2: float
    dhi_w_m2: float
    sun_dir: np.ndarray
    when_unix_s: float

    def image(self, sun_factor: float = 1.0) -> np.ndarray:
        return sun_factor * self.sun_image + self.sky_image


def _rad_scene(site: KnownSite, extra: list[tuple[str, trimesh.Trimesh, tuple]]) -> str:
    out = []
    for k, (name, (mesh, rho)) in enumerate(list(site.parts.items()) +
                                            [(n, (m, r)) for n, m, r in extra]):
        out.append(material(f"m{k}", rho))
        out.append(polygons(f"m{k}", mesh.vertices, mesh.faces, name))
    return "".join(out)


def camera_rays(view: PinholeView) -> np.ndarray:
    """(H*W, 6) Radiance rays through every pixel centre, row by row."""
    ys, xs = np.mgrid[0:view.height, 0:view.width]
    pix = np.column_stack([xs.ravel() + 0.5, ys.ravel() + 0.5])
    o, d = view.rays(pix)
    return np.hstack([to_radiance(o), to_radiance(d)])


def render_sky(site: KnownSite, spec: SkySpec, extra=(), procs: int = 1) -> RenderedSky:
    """Render the view under one gendaylit sky (sun and sky apart), with ``extra`` parts
    ``(name, mesh, albedo)`` the estimator is not told of."""
    _, env = radiance_env()
    sky = gendaylit(spec, SITE, env)
    rays = camera_rays(site.view)
    with tempfile.TemporaryDirectory(prefix="daylit-radiance-") as tmp:
        work = Path(tmp)
        (work / "scene.rad").write_text(_rad_scene(site, list(extra)))
        (work / "sky.rad").write_text(sky_rad(sky.skyfunc))
        (work / "sun.rad").write_text(sun_rad(sky.sun_dir_rad, sky.sun_radiance)
                                      if sky.has_sun else "")
        sun_oct = oconv(work / "sun.oct", [work / "sun.rad", work / "scene.rad"], env)
        sky_oct = oconv(work / "sky.oct", [work / "sky.rad", work / "scene.rad"], env)
        sky_only = oconv(work / "skyonly.oct", [work / "sky.rad"], env)
        shape = (site.view.height, site.view.width, 3)
        sun_img = (rtrace(sun_oct, rays, CAMERA_RAYS, env, irradiance=False, procs=procs)
                   .reshape(shape) if sky.has_sun else np.zeros(shape))
        sky_img = rtrace(sky_oct, rays, CAMERA_RAYS, env, irradiance=False,
                         procs=procs).reshape(shape)
        up = np.array([[0.0, 0.0, 0.001, 0.0, 0.0, 1.0]])
        dhi = float(rtrace(sky_only, up, SKY_IRRADIANCE, env).mean())
    when = local_time(spec, SITE["scene"]["timezone"])
    return RenderedSky(sun_img, sky_img, sky.dni if sky.has_sun else 0.0, dhi, sky.sun_dir,
                       when)


def local_time(spec: SkySpec, timezone: str):
    """The moment of a gendaylit condition. gendaylit reads its time as decimal hours of
    local standard time ("9.5"; it takes "9:30" for 9.0): the specs here use decimal hours.
    (Japan, the test site's zone, has no daylight saving time.)"""
    import datetime as dt
    import zoneinfo

    hours = float(spec.hour)
    start = dt.datetime(spec.year, spec.month, spec.day, tzinfo=zoneinfo.ZoneInfo(timezone))
    return (start + dt.timedelta(hours=hours)).timestamp()


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def linearise(codes: np.ndarray) -> np.ndarray:
    """8-bit sRGB codes (H, W, 3) to linear [0, 1] (the standard sRGB curve)."""
    v = codes.astype(np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def camera_frame(radiance: np.ndarray, rng: np.random.Generator, jpeg_quality: int = 85,
                 exposure: float | None = None) -> tuple[np.ndarray, float]:
    """What a camera makes of a radiance image (H, W, 3): RGB uint8 codes after JPEG, and the
    exposure (linear units per W/(m^2 sr)). Auto-exposure puts the 99th percentile at 0.8;
    noise is shot noise (1 % at full scale) and read noise (0.1 %)."""
    if exposure is None:
        exposure = 0.8 / max(float(np.percentile(radiance, 99.0)), 1e-9)
    linear = radiance * exposure
    linear = linear + rng.normal(0.0, 1.0, linear.shape) * np.sqrt(
        (0.01**2) * np.clip(linear, 0, 1) + 0.001**2)
    codes = np.round(srgb_encode(linear) * 255.0).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", codes[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    assert ok
    out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1]
    return np.ascontiguousarray(out), exposure


def last_estimate(estimator, rendered: RenderedSky, sun_dir: np.ndarray, seed: int,
                  frames: int = 4):
    """The last of a stream of ``frames`` estimates (``estimator``: a SceneEstimator) from
    camera frames (:func:`camera_frame`, the stream's own noise seeded by ``seed``, the first
    frame's exposure kept) of one render."""
    rng = np.random.default_rng(seed)
    exposure = None
    for _ in range(frames):
        codes, exposure = camera_frame(rendered.image(), rng, exposure=exposure)
        light = estimator.estimate(linearise(codes), sun_dir, 1.0 / exposure, clip_level=0.99)
    return light


def radiance_version() -> str:
    _, env = radiance_env()
    return subprocess.run(["rtrace", "-version"], env=env, capture_output=True,
                          text=True).stdout.strip()


def render_build_view(build_dir: Path, spec: SkySpec, width: int, height: int,
                      procs: int = 1, view: PinholeView | None = None,
                      rays: list[str] | None = None) -> tuple[RenderedSky, PinholeView]:
    """A build's first fixed view (scaled to ``width`` x ``height``), or ``view`` (a phone's
    pose, at its own size), of its real proxies and ground (``benchmarks.radiance.scene_files``; no
    virtual object) rendered by Radiance under one gendaylit sky for the build's site, with
    rtrace options ``rays`` (default ``CAMERA_RAYS``; ``ACCURATE_CAMERA_RAYS``: no cache)."""
    from benchmarks.radiance import scene_files

    _, env = radiance_env()
    with tempfile.TemporaryDirectory(prefix="daylit-radiance-") as tmp:
        work = Path(tmp)
        files = scene_files(Path(build_dir), work)
        manifest = files["manifest"]
        if view is None:
            view = PinholeView.from_manifest(manifest["views"][0])
            s = width / view.width
            view = PinholeView(np.diag([s, s, 1.0]) @ view.K, view.world_from_camera, width,
                               height)
        width, height = view.width, view.height
        sky = gendaylit(spec, manifest, env)
        (work / "sky.rad").write_text(sky_rad(sky.skyfunc))
        (work / "sun.rad").write_text(sun_rad(sky.sun_dir_rad, sky.sun_radiance))
        parts = [files["files"]["real"], files["files"]["ground"]]
        octree = oconv(work / "all.oct", [work / "sky.rad", work / "sun.rad", *parts], env)
        sky_only = oconv(work / "skyonly.oct", [work / "sky.rad"], env)
        image = rtrace(octree, camera_rays(view), rays or CAMERA_RAYS, env,
                       irradiance=False, procs=procs).reshape(height, width, 3)
        up = np.array([[0.0, 0.0, 0.001, 0.0, 0.0, 1.0]])
        dhi = float(rtrace(sky_only, up, SKY_IRRADIANCE, env).mean())
    when = local_time(spec, manifest["scene"]["timezone"])
    return RenderedSky(image, np.zeros_like(image), sky.dni, dhi, sky.sun_dir, when), view


def render_sky_camera(spec: SkySpec, site: dict, size_px: int = 256) -> tuple[np.ndarray,
                                                                               Sky]:
    """What a zenith-pointing fisheye sky camera (the ideal 180-degree equidistant lens the
    server assumes without a calibration, north up) sees of one gendaylit sky: radiance
    (size_px, size_px, 3) W/(m^2 sr), 0 outside the image circle. The sky is Radiance's
    (rtrace of the gendaylit sky function at every pixel centre); the sun, much smaller than
    a pixel, is added to the pixel that holds its direction as its whole energy over that
    pixel's solid angle (what a pixel integrating the disc reads, far above any clip level).
    ``site``: ``{"scene": {latitude_deg, longitude_deg, timezone}}``."""
    from server.fisheye import FisheyeCamera

    _, env = radiance_env()
    sky = gendaylit(spec, site, env)
    camera = FisheyeCamera.equidistant(size_px, size_px, 180.0)
    pixels = camera.pixel_grid()
    dirs, seen = camera.unproject(pixels)
    seen &= dirs[:, 1] > 0.0
    origins = np.zeros((int(seen.sum()), 3))
    rays = np.hstack([origins, to_radiance(dirs[seen])])
    image = np.zeros((size_px * size_px, 3))
    with tempfile.TemporaryDirectory(prefix="daylit-radiance-") as tmp:
        work = Path(tmp)
        (work / "sky.rad").write_text(sky_rad(sky.skyfunc))
        octree = oconv(work / "sky.oct", [work / "sky.rad"], env)
        image[seen] = rtrace(octree, rays, ["-ab", "0"], env, irradiance=False)
    image = image.reshape(size_px, size_px, 3)
    if sky.has_sun:
        px, ok = camera.project(sky.sun_dir[None, :])
        if ok[0]:
            u, v = np.round(px[0]).astype(int)
            c = np.array([[u, v]], float)
            du = camera.unproject(c + [0.5, 0.0])[0] - camera.unproject(c - [0.5, 0.0])[0]
            dv = camera.unproject(c + [0.0, 0.5])[0] - camera.unproject(c - [0.0, 0.5])[0]
            omega_sr = float(np.linalg.norm(np.cross(du, dv)))
            image[v, u] += sky.dni / omega_sr
    return image, sky


def write_sky_bracket(folder: Path, radiance: np.ndarray, when_unix_s: float,
                      exposures_s=(0.001, 0.005), utc_offset_h: float = 9.0) -> None:
    """A bracket folder (server.brackets) of 8-bit sRGB PNGs of ``radiance`` (H, W, 3) at
    ``exposures_s`` with a camera of linear value 1 per W/(m^2 sr) in 1 s (``[sky] exposure =
    1``), and its ``bracket.json`` with the sky's time."""
    import datetime as dt
    import json

    folder.mkdir(parents=True, exist_ok=True)
    names = {}
    for k, t in enumerate(exposures_s):
        codes = np.round(srgb_encode(radiance * t) * 255.0).astype(np.uint8)
        cv2.imwrite(str(folder / f"{k}.png"), codes[:, :, ::-1])
        names[f"{k}.png"] = t
    tz = dt.timezone(dt.timedelta(hours=utc_offset_h))
    when = dt.datetime.fromtimestamp(when_unix_s, tz).isoformat()
    (folder / "bracket.json").write_text(json.dumps({"exposure_s": names, "time": when}))

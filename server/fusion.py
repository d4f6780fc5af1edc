"""The scene estimate beside a sky camera (issue 16): the sun where the camera cannot see it,
and the two sources' disagreement.

With a sky camera (``[sky] source = camera:...`` or ``replay:...``) and a site camera, and
``[sky] fuse_scene = true``, the site camera's frames also go to a
:class:`server.scenemeter.SceneMeter` (on a worker thread, newest frame only, at most
``[sky] rate_hz`` estimates a second). :meth:`SceneFusion.fuse` then takes each sky-camera
measurement and decides, per part of the light vector:

- the sky's patches: always the sky camera's (it sees the sky's angular distribution);
- the sun: the sky camera's where it measured the disc (``SunSource.MEASURED``: an HDR frame
  or a bracket whose disc did not clip); where it could not (``SunSource.MODEL``: the disc
  clipped, hidden in an 8-bit frame, or outside the lens), the scene estimate's normal
  irradiance (``SunSource.SCENE``, streamed with SUN_ESTIMATED) in the ephemeris direction, if
  an estimate no older than ``[sky] stale_after_s`` exists and saw enough sunlit surface
  (``sun_observable``); otherwise the clear-sky model as before.

Each fused frame also compares the two: the sky's horizontal irradiance (the sky camera's
patch radiances times each patch's projected solid angle, against the estimate's) and, when
the sky camera measured the sun, the sun's normal irradiance. The ratios (sky camera over
scene, grey: the mean of R, G, B) are the median of the last ``WINDOW`` comparisons; one
outside ``[1 / f, f]`` for ``f = [scene] disagreement_factor`` is a warning in
``/api/status`` (``fusion.warning``) and the log: a sky camera that drifts or whose lens fogs,
or a site camera that moved or changed exposure.

That comparison carries the estimate's own sky-model error (5-30 % by the weather), so it
cannot tell a drift of under 25 %. A finer one (:mod:`server.skycheck`): the site camera's
frame is fitted again with the sky camera's *measured* sky as the shape and one free scale;
``sky_camera_gain`` (the sky camera's sky over what the site's pixels say, median of the last
``WINDOW``) stays within a few per cent of 1 whatever the weather, and one outside
``[1 / d, d]`` for ``d = [scene] drift_factor`` is a drift warning.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from dataclasses import replace

import numpy as np

from daylit.spherical import PatchLookup
from daylit.sun import SunSource
from server.measure import Frame, FrameError, Measurement
from server.newest import Newest
from server.sceneestimate import SceneEstimateError, SceneLight
from server.scenemeter import SceneMeter
from server.simsky import hemisphere_grid
from server.skycheck import SkyPatches, sky_camera_gain

log = logging.getLogger("daylit.fusion")

WINDOW = 10  # comparisons in the median of each ratio
MIN_SUN_W_M2 = 10.0  # the sun is compared only when both sources give at least this (grey)
MIN_SKY_W_M2 = 1.0  # ... and the sky when the estimate gives at least this


def projected_solid_angles_sr(tris: np.ndarray) -> np.ndarray:
    """(n,) each dome patch's integral of ``max(0, cos zenith) dOmega`` (sr): a patch of
    radiance ``r`` gives an open horizontal plane ``r`` times it (the upper hemisphere's add
    up to pi). ``tris`` (n, 3, 3): the patches' unit vertices."""
    dirs, weight = hemisphere_grid()
    patch = PatchLookup(np.asarray(tris, float))(dirs)
    return np.bincount(patch, weights=weight, minlength=len(tris))


def grey(rgb) -> float:
    return float(np.mean(rgb))


class SceneFusion:
    """The scene estimate of a site camera's frames, fused into a sky camera's vectors.

    Parameters
    ----------
    meter : SceneMeter of the build's fixed view
    dome_vertices : (n, 3, 3) the build's dome patches (the sky camera's lights)
    disagreement_factor : a ratio outside ``[1 / f, f]`` is a warning
    max_age_s : an estimate older than this (wall clock) is not used
    rate_hz : most estimates per second
    drift_factor : a sky camera gain (:mod:`server.skycheck`) outside ``[1 / d, d]`` is a
        warning
    """

    def __init__(self, meter: SceneMeter, dome_vertices: np.ndarray,
                 disagreement_factor: float = 1.3, max_age_s: float = 5.0,
                 rate_hz: float = 2.0, drift_factor: float = 1.25):
        self.meter = meter
        self.dome_vertices = np.asarray(dome_vertices, float)
        self.drift_factor = float(drift_factor)
        self._gains: collections.deque[float] = collections.deque(maxlen=WINDOW)
        self._patches: SkyPatches | None = None
        self._sky_for_check: tuple[np.ndarray, float] | None = None  # newest sky camera's
        self.projected_sr = projected_solid_angles_sr(dome_vertices)
        self.disagreement_factor = float(disagreement_factor)
        self.max_age_s = float(max_age_s)
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.latest: SceneLight | None = None
        self.latest_wall_s: float | None = None
        self.skipped = 0
        self.last_error = ""
        self.sun_from = ""  # the source of the newest fused frame's sun
        self.sky_camera: dict | None = None  # the newest sky-camera figures compared
        self._sun_ratios: collections.deque[float] = collections.deque(maxlen=WINDOW)
        self._sky_ratios: collections.deque[float] = collections.deque(maxlen=WINDOW)
        self._frames: Newest[Frame] = Newest()
        self._warned = ""

    # ------------------------------------------------------------------------------ input

    def deliver(self, frame: Frame) -> None:
        """The site camera feed's listener: keep the newest frame (never blocks)."""
        self._frames.put(frame)

    async def run_forever(self) -> None:
        """Estimate the newest site-camera frame on a worker thread, at most ``rate_hz``."""
        while True:
            frame = await self._frames.take()
            t0 = time.monotonic()
            try:
                light, gain = await asyncio.to_thread(self._estimate, frame)
            except FrameError as exc:
                self.skipped += 1
                if str(exc) != self.last_error:
                    log.warning("scene estimate beside the sky camera: skipping a site-camera "
                                "frame: %s", exc)
                self.last_error = str(exc)
            else:
                self.latest, self.latest_wall_s = light, time.time()
                self.last_error = ""
                if gain is not None:
                    self._gains.append(gain)
                    self._check()
            await asyncio.sleep(max(0.0, self.period_s - (time.monotonic() - t0)))

    def _estimate(self, frame: Frame) -> tuple[SceneLight, float | None]:
        """(worker thread) The frame's estimate, and the sky camera's gain against it when a
        sky-camera frame has been measured (None when the frame cannot tell)."""
        light, sun = self.meter.estimate(frame)
        sky = self._sky_for_check
        if sky is None or sun.apparent_elevation_deg <= 0.0:
            return light, None
        if self._patches is None:
            self._patches = SkyPatches(self.meter.estimator, self.dome_vertices)
        image, to_linear, clip = self.meter.pixels(frame)
        try:
            gain = sky_camera_gain(self._patches, image, sun.direction, sky[0], sky[1],
                                   self.meter.radiance_per_unit,
                                   clip if np.isfinite(clip) else None, to_linear)
        except SceneEstimateError:
            return light, None
        return light, gain

    # ----------------------------------------------------------------------------- fusing

    def fresh(self, now_s: float | None = None) -> SceneLight | None:
        """The newest estimate if it is at most ``max_age_s`` old, else None."""
        if self.latest is None or self.latest_wall_s is None:
            return None
        now_s = time.time() if now_s is None else now_s
        return self.latest if now_s - self.latest_wall_s <= self.max_age_s else None

    def sky_horizontal_irradiance(self, radiance: np.ndarray) -> np.ndarray:
        """(3,) RGB W/m^2 an open horizontal plane gets from patch radiances (n, 3)."""
        return self.projected_sr @ np.asarray(radiance, float)

    def fuse(self, m: Measurement, now_s: float | None = None) -> Measurement:
        """The sky camera's measurement with the scene's sun where the camera could not
        measure it (see the module's docstring); records the comparison."""
        light = self.fresh(now_s)
        sun = m.sun
        sky_rgb = self.sky_horizontal_irradiance(m.radiance)
        self._sky_for_check = (np.asarray(m.radiance, float).copy(), grey(sky_rgb))
        self.sky_camera = {
            "sky_horizontal_irradiance_W_m2": sky_rgb,
            "sun_normal_irradiance_W_m2": None if sun is None else sun.normal_irradiance_w_m2,
            "sun_source": None if sun is None else sun.source.label,
        }
        if light is None:
            self.sun_from = "" if sun is None else sun.source.label
            return m
        scene_sky = grey(light.sky_horizontal_irradiance)
        if scene_sky >= MIN_SKY_W_M2:
            self._sky_ratios.append(grey(sky_rgb) / scene_sky)
        if sun is not None and sun.source == SunSource.MEASURED and light.sun_observable:
            cam_sun, scene_sun = grey(sun.normal_irradiance_w_m2), \
                grey(light.sun_normal_irradiance)
            if min(cam_sun, scene_sun) >= MIN_SUN_W_M2:
                self._sun_ratios.append(cam_sun / scene_sun)
        self._check()
        if sun is not None and sun.source == SunSource.MODEL and light.sun_observable:
            sun = replace(sun, normal_irradiance_w_m2=np.asarray(
                light.sun_normal_irradiance, float).copy(), source=SunSource.SCENE,
                visible_fraction=1.0)
            m = replace(m, sun=sun)
        self.sun_from = "" if sun is None else sun.source.label
        return m

    def ratios(self) -> tuple[float | None, float | None]:
        """(sun, sky): the median of the recent ratios, sky camera over scene (None: none)."""
        sun = float(np.median(self._sun_ratios)) if self._sun_ratios else None
        sky = float(np.median(self._sky_ratios)) if self._sky_ratios else None
        return sun, sky

    def gain(self) -> float | None:
        """The sky camera's sky over the site's pixels' (median of the recent; None: none)."""
        return float(np.median(self._gains)) if self._gains else None

    def warning(self) -> str:
        """Why the two sources disagree, or "" if they agree within the factors."""
        f = self.disagreement_factor
        out = []
        for what, ratio in zip(("sun normal irradiance", "sky horizontal irradiance"),
                               self.ratios(), strict=True):
            if ratio is not None and not 1.0 / f <= ratio <= f:
                out.append(f"{what}: sky camera / scene estimate = {ratio:.2f}, beyond the "
                           f"factor {f:g}")
        d, gain = self.drift_factor, self.gain()
        if gain is not None and not 1.0 / d <= gain <= d:
            out.append(f"sky camera gain: its sky / the site's pixels' = {gain:.2f}, beyond "
                       f"the drift factor {d:g}")
        if not out:
            return ""
        return ("the sky camera and the scene estimate disagree (" + "; ".join(out)
                + "): a drifting or fogged sky camera, or a moved or re-exposed site camera")

    def _check(self) -> None:
        text = self.warning()
        if text and not self._warned:
            log.warning("%s", text)
        elif self._warned and not text:
            log.info("the sky camera and the scene estimate agree again")
        self._warned = text

    def status(self) -> dict:
        """``fusion`` of ``/api/status``."""
        def rgb(values):
            return None if values is None else [round(float(v), 3) for v in values]

        light = self.latest
        age = None if self.latest_wall_s is None else round(time.time() - self.latest_wall_s, 3)
        sun_ratio, sky_ratio = self.ratios()
        cam = self.sky_camera or {}
        return {
            "sun_from": self.sun_from or None,
            "scene_estimates": self.meter.estimates,
            "scene_age_s": age,
            "scene_skipped_frames": self.skipped,
            "scene_last_error": self.last_error or None,
            "sky_camera": {
                "sun_normal_irradiance_W_m2": rgb(cam.get("sun_normal_irradiance_W_m2")),
                "sun_source": cam.get("sun_source"),
                "sky_horizontal_irradiance_W_m2": rgb(cam.get("sky_horizontal_irradiance_W_m2")),
            },
            "scene": None if light is None else {
                "sun_normal_irradiance_W_m2": rgb(light.sun_normal_irradiance),
                "sky_horizontal_irradiance_W_m2": rgb(light.sky_horizontal_irradiance),
                "sky_type": light.sky_type,
                "sun_observable": light.sun_observable,
                "sky_separable": light.sky_separable,
            },
            "sun_ratio": None if sun_ratio is None else round(sun_ratio, 4),
            "sky_ratio": None if sky_ratio is None else round(sky_ratio, 4),
            "disagreement_factor": self.disagreement_factor,
            "sky_camera_gain": None if self.gain() is None else round(self.gain(), 4),
            "drift_factor": self.drift_factor,
            "warning": self.warning() or None,
        }

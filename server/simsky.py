"""The simulated sky: what a fisheye camera at the site would see, with a known answer.

A CIE clear sky (``daylit.sky.clear_sky``'s shape) with a sun disk at the sun's true position
for the site (NREL SPA via pvlib) at a simulated, optionally accelerated clock. The sun's
direct normal irradiance is the Ineichen clear-sky model's for the site and time
(``daylit.sun``, Linke turbidity ``linke_turbidity``) in the sun's colour, and the sky is
scaled so its diffuse horizontal irradiance (integrated numerically, sun excluded) is
Ineichen's: noon is several times brighter than dusk. A layer of clouds
drifting with the wind that whiten the sky where they are and dim the sun when they pass in
front of it. The image is made the way a camera makes one: the sky's radiance through the
lens model (:class:`server.fisheye.FisheyeCamera`), auto-exposure in third stops, vignetting, a
little sensor noise, clipping at white, the sRGB response curve and 8-bit codes. So the
measuring code meets the real problems (a clipped sun, quantisation, a response curve), while
:meth:`SimulatedSky.sky_at` gives the exact sky, whose patch integrals are the truth the tests
compare with (``daylit.sky.patch_mean_radiance``).

The clock (``[sim] start``) is server.simclock's; the clouds are server.clouds'.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
import time
from dataclasses import dataclass, field
from functools import cached_property
from zoneinfo import ZoneInfo

import numpy as np

from daylit.sky import (
    SUN_ANGULAR_RADIUS_DEG,
    SUN_SOLID_ANGLE_SR,
    CIESky,
    Sky,
    Sun,
    clear_sky,
    direction_from_azimuth_elevation,
    sun_position,
)
from daylit.sun import (
    DEFAULT_LINKE_TURBIDITY,
    LUMINANCE_RGB,
    clear_sky_irradiance,
    day_of_year,
    sun_colour,
)
from server.clouds import CloudLayer, CloudySky
from server.fisheye import FisheyeCamera
from server.measure import Frame
from server.photometry import Photometry, inverse_response_table
from server.simclock import SimClock, daylight_start, next_morning, parse_start, sunset_after

# Linear value of unit radiance at the camera's longest exposure: full scale at 1 W/(m^2 sr),
# about a hundredth of a daylight sky.
MAX_EXPOSURE = 1.0

log = logging.getLogger("daylit.simsky")


def hemisphere_grid(zenith_steps: int = 90, azimuth_steps: int = 180):
    """Directions (m, 3) and weights ``cos(zenith) dOmega`` (m,) of a midpoint grid over the
    upper hemisphere (the weights add up to pi)."""
    dz = (math.pi / 2) / zenith_steps
    da = 2 * math.pi / azimuth_steps
    z = (np.arange(zenith_steps) + 0.5) * dz
    a = (np.arange(azimuth_steps) + 0.5) * da
    zz, aa = np.meshgrid(z, a, indexing="ij")
    dirs = np.stack([np.sin(zz) * np.sin(aa), np.cos(zz), -np.sin(zz) * np.cos(aa)], axis=-1)
    weight = np.cos(zz) * np.sin(zz) * dz * da
    return dirs.reshape(-1, 3), weight.ravel()


_HEMISPHERE = hemisphere_grid()


def diffuse_horizontal_irradiance(sky: Sky, rgb: bool = False):
    """A sky's diffuse horizontal irradiance, sun disk excluded, W/m^2: its luminance
    (``0.2126 R + 0.7152 G + 0.0722 B``), or (3,) RGB with ``rgb``; numerically integrated
    (90 x 180 midpoint grid, about 0.1 % for the CIE skies)."""
    dirs, weight = _HEMISPHERE
    e = weight @ sky.radiance(dirs)
    return e if rgb else float(LUMINANCE_RGB @ e)


@dataclass
class SimulatedSky:
    """Renders fisheye frames of a simulated sky over a site.

    Parameters
    ----------
    latitude_deg, longitude_deg, elevation_m, timezone :
        The site, as in the manifest's ``scene``.
    camera : FisheyeCamera
        The simulated lens (default: equidistant, 640 x 640, 180 degrees, north up).
    clock : SimClock
        Simulated time.
    clouds : CloudLayer
    photometry : Photometry
        The simulated camera's response curve and vignetting (the measuring side should be
        configured the same way, as it would be after calibrating a real camera).
    noise : float
        Standard deviation of sensor noise, as a fraction of full scale.
    keep_daylight : bool
        The ``auto`` clock: when the simulated sun sets, go on at the next morning
        (:meth:`now`).
    """

    latitude_deg: float
    longitude_deg: float
    elevation_m: float
    timezone: str
    camera: FisheyeCamera
    clock: SimClock
    clouds: CloudLayer
    photometry: Photometry = field(default_factory=Photometry)
    noise: float = 0.002
    seed: int = 0
    keep_daylight: bool = False
    linke_turbidity: float = DEFAULT_LINKE_TURBIDITY
    _sunset_s: float | None = field(default=None, init=False, repr=False)

    @classmethod
    def for_site(
        cls,
        latitude_deg: float,
        longitude_deg: float,
        elevation_m: float,
        timezone: str,
        camera: FisheyeCamera | None = None,
        cloud_cover: float = 0.3,
        clock_speed: float = 1.0,
        start: str | None = None,
        seed: int = 0,
        noise: float = 0.002,
        size_px: int = 640,
    ) -> SimulatedSky:
        if not 0.0 <= cloud_cover <= 1.0:
            raise ValueError(f"cloud cover must be between 0 and 1, got {cloud_cover}")
        camera = camera or FisheyeCamera.equidistant(size_px, size_px)
        # A fixed default start keeps benchmarks and tests reproducible; "auto" for live use.
        if start == "auto":
            start_s = daylight_start(latitude_deg, longitude_deg, elevation_m, timezone)
        else:
            start_s = parse_start(start or "2026-06-21T10:30", timezone)
        return cls(
            latitude_deg,
            longitude_deg,
            elevation_m,
            timezone,
            camera,
            SimClock(start_s, clock_speed),
            CloudLayer(cover=cloud_cover, seed=seed),
            noise=noise,
            seed=seed,
            keep_daylight=start == "auto",
        )

    def now(self, wall_s: float | None = None) -> float:
        """The simulated time now; with ``keep_daylight``, past sunset it jumps to the next
        morning (and logs it)."""
        t = self.clock.now(wall_s)
        if not self.keep_daylight:
            return t
        site = (self.latitude_deg, self.longitude_deg, self.elevation_m)
        if self._sunset_s is None:
            self._sunset_s = sunset_after(*site, t)
        if t >= self._sunset_s:
            morning = next_morning(*site, self.timezone, t)
            self.clock.jump(morning, wall_s)
            self._sunset_s = sunset_after(*site, morning)
            local = dt.datetime.fromtimestamp(morning, ZoneInfo(self.timezone))
            log.info("simulated sky: the sun has set at the site; going on at %s",
                     local.isoformat(timespec="minutes"))
            t = morning
        return t

    @cached_property
    def _pixel_dirs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Site directions of every pixel centre, which are sky, and the vignetting gain."""
        dirs, ok = self.camera.unproject(self.camera.pixel_grid())
        sky = ok & (dirs[:, 1] >= 0.0)
        theta = np.arccos(np.clip((dirs @ self.camera.site_from_camera)[:, 2], -1, 1))
        return dirs, sky, self.photometry.vignetting_gain(theta)

    @cached_property
    def _code_table(self) -> np.ndarray:
        """Linear value -> 8-bit code: the inverse of the measuring side's table."""
        table = inverse_response_table(self.photometry.response, 256)  # code -> linear
        return table

    def sun_at(self, sky_time_s: float) -> tuple[float, float]:
        """True apparent sun azimuth and elevation (degrees) at the site."""
        when = dt.datetime.fromtimestamp(sky_time_s, tz=dt.UTC)
        return sun_position(self.latitude_deg, self.longitude_deg, self.elevation_m, when)

    def clear_sky_at(self, elevation_deg: float, sky_time_s: float) -> tuple[float, float]:
        """Ineichen's clear-sky DNI and DHI (W/m^2) at the site for a sun at this apparent
        elevation at that time."""
        dni, dhi = clear_sky_irradiance([90.0 - elevation_deg], day_of_year([sky_time_s]),
                                        self.elevation_m, self.linke_turbidity)
        return float(dni[0]), float(dhi[0])

    def sky_at(self, sky_time_s: float) -> CloudySky:
        """The exact sky at a simulated time: the truth that frames are measured against."""
        azimuth_deg, elevation_deg = self.sun_at(sky_time_s)
        # Below the horizon the sky keeps the shape (and brightness) of a low sun and fades
        # through twilight.
        shape_elevation = max(elevation_deg, 2.0)
        shape = clear_sky(azimuth_deg, shape_elevation)
        dni, _ = self.clear_sky_at(elevation_deg, sky_time_s)
        _, dhi = self.clear_sky_at(shape_elevation, sky_time_s)
        scale = dhi / max(diffuse_horizontal_irradiance(shape), 1e-9)
        up = elevation_deg > -SUN_ANGULAR_RADIUS_DEG
        clear = CIESky(
            sky_type=shape.sky_type,
            sun_azimuth_deg=azimuth_deg,
            sun_elevation_deg=shape_elevation,
            zenith_radiance=tuple(scale * np.asarray(shape.zenith_radiance)),
            sun_radiance=tuple(dni * sun_colour(elevation_deg) / SUN_SOLID_ANGLE_SR)
            if up else None,
        )
        if clear.sun is not None and elevation_deg < shape_elevation:
            # the disk sits at its true place, not the shape's
            clear.sun = Sun(direction_from_azimuth_elevation(azimuth_deg, elevation_deg),
                            clear.sun.radiance)
        daylight = float(np.clip((elevation_deg + 6.0) / 8.0, 0.0005, 1.0))
        return CloudySky(clear=clear, clouds=self.clouds, sky_time_s=sky_time_s,
                         daylight=daylight)

    def render(self, sky: CloudySky, capture_time_s: float | None = None) -> Frame:
        """A camera frame (RGB uint8) of ``sky`` with its auto-exposure."""
        cam = self.camera
        dirs, is_sky, gain = self._pixel_dirs
        radiance = np.zeros((dirs.shape[0], 3))
        radiance[is_sky] = sky.radiance(dirs[is_sky])
        # Auto-exposure in third stops: the brightest of the sky (not the sun's disc) near 80 %,
        # so only the disc clips (a percentile let the bright circumsolar sky clip too, by a
        # varying amount as the exposure stepped).
        bright = radiance[is_sky].max() if is_sky.any() else 1.0
        exposure = 2.0 ** (round(3.0 * math.log2(0.8 / max(bright, 1e-9))) / 3.0)
        exposure = min(exposure, MAX_EXPOSURE)  # the longest shutter: night stays dark
        linear = radiance * (exposure * gain)[:, None]
        linear = linear.reshape(cam.height, cam.width, 3)
        if sky.sun is not None and sky.sun.direction[1] > -0.01:
            self._add_sun(linear, sky.sun, exposure)
        if self.noise > 0:
            rng = np.random.default_rng(
                (self.seed, int(capture_time_s * 1000) if capture_time_s else 0)
            )
            linear = linear + rng.normal(0.0, self.noise, linear.shape) * np.sqrt(
                np.clip(linear, 0.0, 1.0)
            )
        linear = np.clip(linear, 0.0, 1.0)
        image = self._to_codes(linear)
        return Frame(
            image=image,
            capture_time_s=time.time() if capture_time_s is None else capture_time_s,
            bgr=False,
            exposure=exposure,
            truth=sky,
        )

    def render_at(self, sky_time_s: float, capture_time_s: float | None = None) -> Frame:
        frame = self.render(self.sky_at(sky_time_s), capture_time_s)
        frame.sky_time_s = sky_time_s  # the sun is where it is at the simulated time
        return frame

    def _to_codes(self, linear: np.ndarray) -> np.ndarray:
        """Nearest 8-bit code whose linear value is closest (the table is monotonic)."""
        table = self._code_table[:, 0].astype(np.float64)
        mid = 0.5 * (table[1:] + table[:-1])
        return np.searchsorted(mid, linear).astype(np.uint8)

    def _add_sun(self, linear: np.ndarray, sun: Sun, exposure: float, s: int = 8) -> None:
        """Spread the sun disk's energy over the pixels it covers (sub-pixel sampled)."""
        cam = self.camera
        px, ok = cam.project(sun.direction[None, :])
        if not ok[0]:
            return
        cu, cv = np.round(px[0]).astype(int)
        r = 3
        us = np.arange(cu - r, cu + r + 1)
        vs = np.arange(cv - r, cv + r + 1)
        us = us[(us >= 0) & (us < cam.width)]
        vs = vs[(vs >= 0) & (vs < cam.height)]
        if us.size == 0 or vs.size == 0:
            return
        gu, gv = np.meshgrid(us, vs)
        centres = np.stack([gu.ravel(), gv.ravel()], axis=-1).astype(float)
        off = (np.arange(s) + 0.5) / s - 0.5
        sub = np.stack(np.meshgrid(off, off), axis=-1).reshape(-1, 2)
        dirs, _ = cam.unproject((centres[:, None, :] + sub[None]).reshape(-1, 2))
        inside = (dirs @ sun.direction >= math.cos(math.radians(SUN_ANGULAR_RADIUS_DEG)))
        inside &= dirs[:, 1] >= 0.0
        frac = inside.reshape(len(centres), -1).mean(axis=1)
        # Pixel solid angle from neighbouring pixel centres.
        du = cam.unproject(centres + [0.5, 0])[0] - cam.unproject(centres - [0.5, 0])[0]
        dv = cam.unproject(centres + [0, 0.5])[0] - cam.unproject(centres - [0, 0.5])[0]
        omega_px = np.linalg.norm(np.cross(du, dv), axis=-1)
        energy = sun.radiance[None, :] * SUN_SOLID_ANGLE_SR * frac[:, None]  # W/m^2 per pixel
        if frac.sum() > 0:
            energy /= frac.sum()  # the whole disk lands somewhere, even if sampled coarsely
        add = energy / omega_px[:, None] * exposure
        linear[gv.ravel(), gu.ravel()] += add

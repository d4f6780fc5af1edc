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

The clock (``[sim] start``): ``auto``, the default, keeps the demo in daylight whenever it is
run: it starts now if the sun is up at the site (at least ``DAYLIGHT_ELEVATION_DEG``), else at
the next ``MORNING_HOUR`` o'clock local time there, and when the simulated sun sets it goes on
at the next morning's ``MORNING_HOUR`` again. ``now`` and an ISO date-time follow the clock
through the night.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
import time
from dataclasses import dataclass, field
from functools import cached_property
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import numpy as np
from scipy import ndimage

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
from server.fisheye import FisheyeCamera
from server.measure import Frame
from server.photometry import Photometry, inverse_response_table

# Linear value of unit radiance at the camera's longest exposure: full scale at 1 W/(m^2 sr),
# about a hundredth of a daylight sky.
MAX_EXPOSURE = 1.0

# The "auto" clock: the sun counts as up from this elevation (the simulated sky is in full
# daylight from 2 degrees), and a new day starts at this local hour.
DAYLIGHT_ELEVATION_DEG = 5.0
MORNING_HOUR = 10

log = logging.getLogger("daylit.simsky")


@dataclass
class SimClock:
    """Simulated time: ``start_s`` (Unix seconds) at wall time ``wall_start_s``, running at
    ``speed`` simulated seconds per wall second."""

    start_s: float
    speed: float = 1.0
    wall_start_s: float = field(default_factory=time.time)

    def now(self, wall_s: float | None = None) -> float:
        wall = time.time() if wall_s is None else wall_s
        return self.start_s + self.speed * (wall - self.wall_start_s)

    def jump(self, sky_time_s: float, wall_s: float | None = None) -> None:
        """Go on from ``sky_time_s`` at wall time ``wall_s`` (now), at the same speed."""
        self.start_s = sky_time_s
        self.wall_start_s = time.time() if wall_s is None else wall_s


def _site_zone(timezone: str) -> ZoneInfo:
    try:
        return ZoneInfo(timezone)
    except (ZoneInfoNotFoundError, ValueError):
        raise ValueError(f"unknown time zone {timezone!r} in the manifest") from None


def _elevations(latitude_deg: float, longitude_deg: float, elevation_m: float,
                times_s: np.ndarray) -> np.ndarray:
    """Apparent sun elevation (degrees) at the site at Unix times (vectorised SPA)."""
    import pandas as pd

    from daylit.sky import sun_positions

    times = pd.DatetimeIndex(pd.to_datetime(np.asarray(times_s, dtype=np.float64), unit="s",
                                            utc=True))
    return sun_positions(latitude_deg, longitude_deg, elevation_m, times)[1]


def next_morning(latitude_deg: float, longitude_deg: float, elevation_m: float,
                 timezone: str, after_s: float) -> float:
    """The first ``MORNING_HOUR`` o'clock local time at the site after ``after_s``.

    Where the sun is below ``DAYLIGHT_ELEVATION_DEG`` then (a polar winter), the time of that
    day's highest sun instead: the brightest the day gets.
    """
    zone = _site_zone(timezone)
    local = dt.datetime.fromtimestamp(after_s, zone)
    morning = dt.datetime.combine(local.date(), dt.time(MORNING_HOUR), zone)
    if morning.timestamp() <= after_s:
        morning = dt.datetime.combine(local.date() + dt.timedelta(days=1), dt.time(MORNING_HOUR),
                                      zone)
    start_s = morning.timestamp()
    if _elevations(latitude_deg, longitude_deg, elevation_m, [start_s])[0] >= \
            DAYLIGHT_ELEVATION_DEG:
        return start_s
    midnight_s = dt.datetime.combine(morning.date(), dt.time(0), zone).timestamp()
    times = midnight_s + np.arange(0.0, 86400.0, 600.0)
    return float(times[np.argmax(_elevations(latitude_deg, longitude_deg, elevation_m, times))])


def daylight_start(latitude_deg: float, longitude_deg: float, elevation_m: float,
                   timezone: str, now_s: float | None = None) -> float:
    """``start = "auto"``: now if the sun is up at the site, else the next morning there."""
    now_s = time.time() if now_s is None else now_s
    if _elevations(latitude_deg, longitude_deg, elevation_m, [now_s])[0] >= \
            DAYLIGHT_ELEVATION_DEG:
        return now_s
    return next_morning(latitude_deg, longitude_deg, elevation_m, timezone, now_s)


def sunset_after(latitude_deg: float, longitude_deg: float, elevation_m: float,
                 start_s: float, horizon_s: float = 2 * 86400.0, step_s: float = 300.0) -> float:
    """When the sun, up at some time after ``start_s``, next goes below
    ``DAYLIGHT_ELEVATION_DEG`` (to ``step_s``); +inf when it does not set within ``horizon_s``
    (midnight sun) or never rises (polar night)."""
    times = start_s + np.arange(0.0, horizon_s, step_s)
    up = _elevations(latitude_deg, longitude_deg, elevation_m, times) >= DAYLIGHT_ELEVATION_DEG
    if not up.any():
        return math.inf
    first_up = int(np.argmax(up))
    down = np.flatnonzero(~up[first_up:])
    return math.inf if down.size == 0 else float(times[first_up + down[0]])


def parse_start(text: str | None, timezone: str) -> float:
    """Unix time from ``"now"``/None or an ISO date-time; a naive time is local at the site.

    (``"auto"`` depends on the site's sun: :func:`daylight_start`.)
    """
    if text is None or text == "now":
        return time.time()
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:
        raise ValueError(
            f"sim start {text!r} is not an ISO date-time such as 2026-06-21T10:00"
        ) from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=_site_zone(timezone))
    return when.timestamp()


@dataclass
class CloudLayer:
    """A flat cloud deck at ``height_m`` whose opacity pattern drifts with the wind.

    The pattern is band-limited noise (a sum of blurred random fields on a periodic grid of
    ``tile_m`` metres), thresholded so that about ``cover`` of the sky is cloud, with soft edges.
    """

    cover: float = 0.3
    height_m: float = 2000.0
    wind_mps: float = 12.0
    wind_toward_deg: float = 70.0  # azimuth the clouds move toward
    tile_m: float = 20000.0
    seed: int = 0
    softness: float = 0.12

    @cached_property
    def _field(self) -> np.ndarray:
        """(256, 256) noise in [0, 1], uniformly distributed (so ``cover`` is a fraction)."""
        rng = np.random.default_rng(self.seed)
        size = 256
        total = np.zeros((size, size))
        for sigma, amp in ((24.0, 1.0), (10.0, 0.5), (4.0, 0.2)):
            layer = ndimage.gaussian_filter(rng.standard_normal((size, size)), sigma, mode="wrap")
            total += amp * layer / layer.std()
        ranks = np.argsort(np.argsort(total.ravel()))
        return (ranks / (ranks.size - 1)).reshape(size, size)

    def opacity(self, dirs: np.ndarray, sky_time_s: float) -> np.ndarray:
        """Cloud opacity in [0, 1] for unit site directions ``(m, 3)`` at a simulated time."""
        if self.cover <= 0.0:
            return np.zeros(dirs.shape[0])
        up = np.maximum(dirs[:, 1], 0.03)  # keep the horizon finite: a far deck looks uniform
        x = dirs[:, 0] * self.height_m / up
        z = dirs[:, 2] * self.height_m / up
        drift = self.wind_mps * sky_time_s
        a = math.radians(self.wind_toward_deg)
        # The deck moves toward azimuth a; sample the pattern at the point that arrived here.
        x = x - drift * math.sin(a)
        z = z + drift * math.cos(a)
        size = self._field.shape[0]
        coords = np.stack([(z / self.tile_m * size) % size, (x / self.tile_m * size) % size])
        noise = ndimage.map_coordinates(self._field, coords, order=1, mode="grid-wrap")
        edge = (noise - (1.0 - self.cover)) / self.softness
        near = np.clip(0.5 + edge, 0.0, 1.0)
        # Toward the horizon the deck's detail shrinks below what any camera resolves: blend
        # into its mean, as a distant deck looks like haze.
        w = np.clip((dirs[:, 1] - 0.08) / 0.25, 0.0, 1.0)
        return (w * near + (1.0 - w) * self.cover) * (dirs[:, 1] > 0.0)


@dataclass
class CloudySky(Sky):
    """A clear CIE sky with a cloud layer over it at one instant (a ``daylit.sky.Sky``).

    Clouds are lit white-grey, brighter toward the sun (forward scattering); the sun disk's
    radiance falls as ``exp(-4 opacity)`` where a cloud covers it.
    """

    clear: CIESky | None = None
    clouds: CloudLayer | None = None
    sky_time_s: float = 0.0
    daylight: float = 1.0  # 0 at night, 1 in full day (twilight in between)

    def __post_init__(self):
        sun = self.clear.sun if self.clear is not None else None
        if sun is not None:
            tau = self.clouds.opacity(sun.direction[None, :], self.sky_time_s)[0]
            self.sun = Sun(sun.direction, sun.radiance * math.exp(-4.0 * tau) * self.daylight)
            self.sun_opacity = float(tau)
        else:
            self.sun = None
            self.sun_opacity = 0.0

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        clear = self.clear.radiance(dirs)
        tau = self.clouds.opacity(dirs, self.sky_time_s)[:, None]
        sun_dir = self.clear._sun_dir
        near_sun = np.clip(dirs @ sun_dir, 0.0, 1.0) ** 16
        # A thicker deck (more cover) lets less light through: overcast days are dimmer.
        thickness = 1.2 - 0.8 * self.clouds.cover
        grey = thickness * 1.6 * float(np.mean(self.clear.zenith_radiance)) * (1.0 + 6.0 * near_sun)
        cloud = grey[:, None] * np.array([1.0, 1.0, 1.02])
        out = ((1.0 - tau) * clear + tau * cloud) * self.daylight
        out[dirs[:, 1] < 0.0] = 0.0
        return out


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

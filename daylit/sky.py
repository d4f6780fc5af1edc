"""Analytic daylight skies and the sun, as linear RGB radiance over sky directions.

Used by ``daylit probe`` (named test skies), by the server's simulated sky, and by the tests
as known answers. Directions follow docs/architecture.md, "Frames, units, the index rule":
world frame +X east, +Y up, -Z north; azimuth is clockwise from north toward east, elevation
above the horizon.

Radiance is in W/(m^2 sr) per RGB channel, roughly broadband-physical: a clear noon sky gives
a horizontal diffuse irradiance near 100 and a direct normal sun irradiance near 900.

The sky models are the CIE general sky (ISO 15469 / CIE S 011): relative luminance is
``f(chi) phi(Z) / (f(Z_s) phi(0))`` with the gradation ``phi`` and indicatrix ``f`` of one of the
standard types; type 1 is the CIE overcast sky (Moon & Spencer), type 12 the CIE clear sky.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field

import numpy as np

from daylit.spherical import normalize, sample_triangles

SUN_ANGULAR_RADIUS_DEG = 0.2666
SUN_SOLID_ANGLE_SR = 2.0 * np.pi * (1.0 - np.cos(np.radians(SUN_ANGULAR_RADIUS_DEG)))

# The 15 CIE standard general skies (ISO 15469:2004 / CIE S 011/E:2003): gradation (a, b)
# and indicatrix (c, d, e) parameters. 1-5 overcast, 6-10 partly cloudy, 11-15 clear.
CIE_SKY_TYPES = {
    1: (4.0, -0.70, 0.0, -1.0, 0.00),  # CIE standard overcast, steep gradation
    2: (4.0, -0.70, 2.0, -1.5, 0.15),  # overcast, steep gradation, slight brightening to sun
    3: (1.1, -0.80, 0.0, -1.0, 0.00),  # overcast, moderate gradation, uniform in azimuth
    4: (1.1, -0.80, 2.0, -1.5, 0.15),  # overcast, moderate gradation, slight brightening
    5: (0.0, -1.00, 0.0, -1.0, 0.00),  # sky of uniform luminance
    6: (0.0, -1.00, 2.0, -1.5, 0.15),  # partly cloudy, no gradation, slight brightening
    7: (0.0, -1.00, 5.0, -2.5, 0.30),  # partly cloudy, brighter circumsolar region
    8: (0.0, -1.00, 10.0, -3.0, 0.45),  # partly cloudy, distinct solar corona
    9: (-1.0, -0.55, 2.0, -1.5, 0.15),  # partly cloudy, obscured sun
    10: (-1.0, -0.55, 5.0, -2.5, 0.30),  # partly cloudy, brighter circumsolar region
    11: (-1.0, -0.55, 10.0, -3.0, 0.45),  # white-blue sky, distinct solar corona
    12: (-1.0, -0.32, 10.0, -3.0, 0.45),  # CIE standard clear sky, low turbidity
    13: (-1.0, -0.32, 16.0, -3.0, 0.30),  # CIE standard clear sky, polluted atmosphere
    14: (-1.0, -0.15, 16.0, -3.0, 0.30),  # cloudless turbid sky, broad solar corona
    15: (-1.0, -0.15, 24.0, -2.8, 0.15),  # white-blue turbid sky, broad solar corona
}


def direction_from_azimuth_elevation(azimuth_deg, elevation_deg) -> np.ndarray:
    """Unit world direction(s), shape ``(..., 3)``, from azimuth (cw from north) and elevation."""
    az = np.radians(np.asarray(azimuth_deg, dtype=float))
    el = np.radians(np.asarray(elevation_deg, dtype=float))
    return np.stack([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)], axis=-1)


def azimuth_elevation_from_direction(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (deg, cw from north, in [0, 360)) and elevation (deg) of world directions."""
    d = normalize(np.asarray(dirs, dtype=float))
    azimuth = np.degrees(np.arctan2(d[..., 0], -d[..., 2])) % 360.0
    elevation = np.degrees(np.arcsin(np.clip(d[..., 1], -1.0, 1.0)))
    return azimuth, elevation


def sun_position(
    latitude_deg: float, longitude_deg: float, elevation_m: float, when: dt.datetime
) -> tuple[float, float]:
    """Apparent (refracted) solar azimuth and elevation in degrees, by NREL SPA (pvlib), at
    the site's standard pressure (:func:`daylit.sun.sun_position` has all the parameters).

    ``when`` must be timezone-aware.
    """
    from daylit.sun import sun_position as spa

    if when.tzinfo is None:
        raise ValueError("sun_position needs a timezone-aware datetime")
    pos = spa(latitude_deg, longitude_deg, elevation_m, when)
    return float(pos.azimuth_deg[0]), float(pos.apparent_elevation_deg[0])


def sun_positions(
    latitude_deg: float, longitude_deg: float, elevation_m: float, times
) -> tuple[np.ndarray, np.ndarray]:
    """Vectorized :func:`sun_position` over a pandas ``DatetimeIndex`` (tz-aware)."""
    from daylit.sun import sun_position as spa

    pos = spa(latitude_deg, longitude_deg, elevation_m, times)
    return pos.azimuth_deg, pos.apparent_elevation_deg


def air_mass(sun_elevation_deg: float) -> float:
    """The simple air mass ``1 / sin(elevation)`` of the sky models (at least 1 degree up, at
    most 20): not a physical model, the shape of :func:`sun_warmth` and :func:`clear_sky`."""
    return 1.0 / max(np.sin(np.radians(max(sun_elevation_deg, 1.0))), 0.05)


SUN_WARMING_PER_AIR_MASS = np.array([0.02, 0.05, 0.11])  # RGB extinction beyond air mass 1


def sun_warmth(sun_elevation_deg: float) -> np.ndarray:
    """The sun's relative RGB transmission (3,), 1 at the zenith, warming as it sets."""
    return np.exp(-SUN_WARMING_PER_AIR_MASS * (air_mass(sun_elevation_deg) - 1.0))


@dataclass
class Sun:
    """A sun disk: direction (unit, world), radiance RGB in W/(m^2 sr), solid angle in sr."""

    direction: np.ndarray
    radiance: np.ndarray
    solid_angle_sr: float = SUN_SOLID_ANGLE_SR

    @property
    def normal_irradiance(self) -> np.ndarray:
        """Direct normal irradiance RGB, W/m^2."""
        return self.radiance * self.solid_angle_sr


@dataclass
class Sky:
    """Base class: a sky's radiance over directions plus an optional sun disk."""

    sun: Sun | None = field(default=None, init=False)

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        """Sky radiance (without the sun disk), shape ``(m, 3)``, for unit directions ``(m, 3)``.

        Directions below the horizon get zero.
        """
        raise NotImplementedError


@dataclass
class UniformSky(Sky):
    """The same radiance ``L`` (RGB) from every direction above the horizon."""

    L: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        out = np.broadcast_to(np.asarray(self.L, dtype=float), (dirs.shape[0], 3)).copy()
        out[dirs[:, 1] < 0.0] = 0.0
        return out


@dataclass
class CIESky(Sky):
    """A CIE general sky of a given type, scaled to a zenith radiance, with an optional sun.

    Parameters
    ----------
    sky_type : int
        Key of :data:`CIE_SKY_TYPES` (1 overcast, 5 uniform, 7 partly cloudy, 12 clear).
    sun_azimuth_deg, sun_elevation_deg : float
        Sun position; it shapes the sky's indicatrix even when ``sun_radiance`` is zero.
    zenith_radiance : RGB
        Radiance at the zenith, W/(m^2 sr).
    sun_radiance : RGB or None
        Radiance of the solar disk; ``None`` for none (overcast).
    horizon_tint : RGB
        Multiplies the colour toward the horizon and around the sun (whiter), while the zenith
        keeps ``zenith_radiance``'s colour: a simple, smooth stand-in for sky colour.
    """

    sky_type: int = 12
    sun_azimuth_deg: float = 180.0
    sun_elevation_deg: float = 45.0
    zenith_radiance: tuple[float, float, float] = (20.0, 26.0, 40.0)
    sun_radiance: tuple[float, float, float] | None = None
    horizon_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self):
        if self.sky_type not in CIE_SKY_TYPES:
            known = sorted(CIE_SKY_TYPES)
            raise ValueError(f"unknown CIE sky type {self.sky_type}; known: {known}")
        self._sun_dir = direction_from_azimuth_elevation(
            self.sun_azimuth_deg, self.sun_elevation_deg
        )
        self.sun = (
            None
            if self.sun_radiance is None or self.sun_elevation_deg <= -SUN_ANGULAR_RADIUS_DEG
            else Sun(self._sun_dir, np.asarray(self.sun_radiance, dtype=float))
        )

    def relative_luminance(self, dirs: np.ndarray) -> np.ndarray:
        """Luminance relative to the zenith, shape ``(m,)`` (1 at the zenith)."""
        a, b, c, d, e = CIE_SKY_TYPES[self.sky_type]
        cos_z = np.clip(dirs[:, 1], 1e-6, 1.0)
        z_sun = np.radians(90.0 - self.sun_elevation_deg)
        chi = np.arccos(np.clip(dirs @ self._sun_dir, -1.0, 1.0))

        def gradation(cos_zenith):
            return 1.0 + a * np.exp(b / cos_zenith)

        def indicatrix(angle):
            return 1.0 + c * (np.exp(d * angle) - np.exp(d * np.pi / 2)) + e * np.cos(angle) ** 2

        return (indicatrix(chi) * gradation(cos_z)) / (indicatrix(z_sun) * gradation(1.0))

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        rel = self.relative_luminance(dirs)
        # Colour: the zenith colour, whitened toward the horizon and the sun.
        toward_horizon = 1.0 - np.clip(dirs[:, 1], 0.0, 1.0)
        near_sun = np.clip(dirs @ self._sun_dir, 0.0, 1.0) ** 8
        whiten = np.clip(0.6 * toward_horizon**2 + 0.5 * near_sun, 0.0, 1.0)
        zen = np.asarray(self.zenith_radiance, dtype=float)
        white = np.full(3, zen.mean()) * np.asarray(self.horizon_tint, dtype=float)
        colour = (1.0 - whiten)[:, None] * zen + whiten[:, None] * white
        out = rel[:, None] * colour
        out[dirs[:, 1] < 0.0] = 0.0
        return out


def overcast_sky(zenith_radiance: float = 30.0) -> CIESky:
    """The CIE standard overcast sky, neutral grey, no sun."""
    return CIESky(sky_type=1, sun_elevation_deg=90.0, zenith_radiance=(zenith_radiance,) * 3)


def clear_sky(sun_azimuth_deg: float, sun_elevation_deg: float, turbid: bool = False) -> CIESky:
    """A CIE clear sky with a sun disk of about 900 W/m^2 direct normal irradiance.

    The sun's colour warms as it sets (more air mass); a simple stand-in, not a spectral model.
    """
    warm = sun_warmth(sun_elevation_deg)
    dni = 900.0 * warm * np.exp(-0.03 * (air_mass(sun_elevation_deg) - 1.0))
    return CIESky(
        sky_type=7 if turbid else 12,
        sun_azimuth_deg=sun_azimuth_deg,
        sun_elevation_deg=sun_elevation_deg,
        zenith_radiance=(14.0, 20.0, 34.0),
        sun_radiance=tuple(dni / SUN_SOLID_ANGLE_SR),
    )


def patch_mean_radiance(
    sky: Sky, patch_vertices: np.ndarray, samples_per_side: int = 12, include_sun: bool = True
) -> np.ndarray:
    """The light vector of a sky: mean radiance of each patch, shape ``(n, 3)``.

    Integrates the sky's radiance over each spherical triangle with a stratified grid of
    ``samples_per_side^2`` points (solid-angle weighted), then adds the sun disk to the patch
    that contains its centre as ``L_sun * omega_sun / omega_patch`` (the disk is far smaller
    than any patch). This is ``r_i`` (docs/architecture.md) before any camera is involved.
    """
    from daylit.spherical import PatchLookup, solid_angle

    k = samples_per_side
    grid = (np.arange(k) + 0.5) / k
    uv = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 1, 2)
    uv = np.broadcast_to(uv, (k * k, patch_vertices.shape[0], 2))
    dirs, weight = sample_triangles(patch_vertices, uv)  # (s, n, 3), (s, n)
    rad = sky.radiance(dirs.reshape(-1, 3)).reshape(dirs.shape[0], dirs.shape[1], 3)
    mean = np.einsum("sn,snc->nc", weight, rad) / weight.sum(axis=0)[:, None]
    if include_sun and sky.sun is not None and sky.sun.direction[1] > 0.0:
        patch = PatchLookup(patch_vertices)(sky.sun.direction[None, :])[0]
        omega = solid_angle(patch_vertices[patch : patch + 1])[0]
        mean[patch] += sky.sun.radiance * sky.sun.solid_angle_sr / omega
    return mean

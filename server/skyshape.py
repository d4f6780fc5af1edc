"""The model sky's shape for the scene estimate (server.sceneestimate, issue 16).

The scene estimate measures only the sky's brightness; its angular distribution is a CIE general
sky (``daylit.sky.CIESky``; under a clear sky the estimator then takes Perez's all-weather sky,
``server.perezsky``, through :func:`unit_sky`'s ``perez``) chosen by the estimated ratio of
the sun's normal irradiance to the sky's horizontal irradiance (:func:`sky_type_for_ratio`),
scaled to an open horizontal irradiance of 1 (:func:`unit_sky`). :func:`tilted_irradiance`
gives what that sky puts on an unobstructed surface of any tilt (the one-bounce term: a wall lit
by an overcast sky).

Directions are site-frame unit vectors (+X east, +Y up, -Z north); irradiances per unit of the
open horizontal irradiance.
"""

from __future__ import annotations

import math

import numpy as np

from daylit.sky import CIESky, azimuth_elevation_from_direction
from server.perezsky import PerezShape

OVERCAST_RATIO = 0.5  # E_sun / k below this: one of the overcast CIE skies (OVERCAST_TYPES)
# CIE overcast with steep gradation: uniform in azimuth (1, the CIE standard overcast) or with
# a slight brightening toward the sun (2); the estimate takes the one that fits the frame best
OVERCAST_TYPES = (1, 2)
# Perez's sky clearness at and above which the sky is clear (the CIE clear sky, type 12); below
# it, partly cloudy (7). 4.5 is the lower edge of Perez's clear bins (7 and 8; Perez et al.
# 1990, the bins of the all-weather sky model gendaylit uses). It replaced a ratio of 3.0, which
# did not depend on the sun's height: for a sun 43 degrees high it called a sky of clearness 2.9
# (Perez's bin 6, partly cloudy) clear, and Radiance's intermediate sky (DNI/DHI 2.0, clearness
# 2.28) fitted with the clear sky read a ratio above 3 and stayed there (docs/web.md).
CLEAR_CLEARNESS = 4.5


def sky_clearness(sun_to_sky: float, sun_elevation_deg: float) -> float:
    """Perez's sky clearness ``((DHI + DNI) / DHI + 1.041 Z^3) / (1 + 1.041 Z^3)`` (Z the sun's
    zenith angle in radians) for a ratio ``DNI / DHI`` of the sun's normal irradiance to the
    sky's horizontal irradiance: 1 under overcast, about 2-4.5 partly cloudy, above clear."""
    z = math.radians(90.0 - min(max(sun_elevation_deg, 0.0), 90.0))
    k = 1.041 * z**3
    return (1.0 + max(sun_to_sky, 0.0) + k) / (1.0 + k)


def sky_type_for_ratio(sun_to_sky: float, sun_elevation_deg: float = 90.0) -> int:
    """The CIE general sky for a ratio of sun normal irradiance to sky horizontal irradiance
    and the sun's elevation: ``OVERCAST_TYPES[0]`` (standing for the overcast family) below
    ``OVERCAST_RATIO``, 12 (clear) from a clearness (:func:`sky_clearness`) of
    ``CLEAR_CLEARNESS``, 7 (partly cloudy) between. (Coarse on purpose: the isotropic share
    fitted beside it adapts the shape.)"""
    if sun_to_sky < OVERCAST_RATIO:
        return OVERCAST_TYPES[0]
    return 12 if sky_clearness(sun_to_sky, sun_elevation_deg) >= CLEAR_CLEARNESS else 7


def unit_sky(sky_type: int, sun_dir: np.ndarray, perez: tuple[float, float] | None = None
             ) -> tuple[CIESky | PerezShape, float]:
    """A grey CIE sky of this type for the sun direction (or, with ``perez`` = (clearness,
    brightness), the Perez all-weather sky of that state: ``server.perezsky``), and the factor
    that scales its radiance to an open horizontal irradiance of 1 W/m^2 (sun excluded)."""
    if perez is not None:
        sky = PerezShape(perez[0], perez[1], np.asarray(sun_dir, float))
        return sky, 1.0 / _horizontal_irradiance(sky)
    az, el = azimuth_elevation_from_direction(sun_dir)
    sky = CIESky(sky_type=sky_type, sun_azimuth_deg=float(az),
                 sun_elevation_deg=float(max(el, 0.0)), zenith_radiance=(1.0, 1.0, 1.0))
    return sky, 1.0 / _horizontal_irradiance(sky)


def upper_hemisphere_grid(steps: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint directions (N, 3) over the upper hemisphere and their solid angles (N,) sr."""
    dz = (math.pi / 2) / steps
    da = 2 * math.pi / (2 * steps)
    z = (np.arange(steps) + 0.5) * dz
    a = (np.arange(2 * steps) + 0.5) * da
    zz, aa = np.meshgrid(z, a, indexing="ij")
    dirs = np.stack([np.sin(zz) * np.sin(aa), np.cos(zz), -np.sin(zz) * np.cos(aa)], -1)
    return dirs.reshape(-1, 3), (np.sin(zz) * dz * da).ravel()


def _horizontal_irradiance(sky: CIESky | PerezShape, steps: int = 48) -> float:
    """An open horizontal plane's irradiance from a sky's relative luminance (midpoint grid)."""
    dirs, d_omega = upper_hemisphere_grid(steps)
    return float((d_omega * dirs[:, 1]) @ sky.relative_luminance(dirs))


# Lambert's clamped cosine in spherical harmonics, per band l = 0, 1, 2 (Ramamoorthi &
# Hanrahan 2001): irradiance = sum over l, m of A_l L_lm Y_lm(n)
SH9_COSINE = np.array([math.pi] + [2.0 * math.pi / 3.0] * 3 + [math.pi / 4.0] * 5)


def tilted_irradiance(sky: CIESky | PerezShape, to_unit: float, normals: np.ndarray) -> np.ndarray:
    """(n,) the irradiance of unobstructed surfaces of unit ``normals`` (n, 3) under a sky
    scaled to an open horizontal irradiance of 1 (``unit_sky``), nothing from below the
    horizon. By the sky's spherical harmonics to l = 2 (exact for an isotropic sky's
    ``(1 + n_y) / 2``, within about 2 % for the CIE skies): a CIE overcast sky's zenith is
    three times as bright as its horizon, so a wall gets about 0.4 of the horizontal
    irradiance, not the isotropic 0.5."""
    from daylit.spherical import sh9_basis

    dirs, d_omega = upper_hemisphere_grid(24)
    coeff = (d_omega * sky.relative_luminance(dirs) * to_unit) @ sh9_basis(dirs)
    return sh9_basis(np.asarray(normals, float)) @ (SH9_COSINE * coeff)

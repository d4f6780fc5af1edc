"""The Perez all-weather sky's shape (Perez, Seals & Michalsky 1993), for the scene estimate.

Perez, R., R. Seals and J. Michalsky, 1993: "All-weather model for sky luminance distribution
- preliminary configuration and validation", Solar Energy 50(3), 235-245 (erratum: Solar
Energy 51(5), 423). The relative luminance of a sky element at zenith angle ``Z`` and angle
``gamma`` from the sun has the CIE general sky's form (``daylit.sky.CIESky``)

    lv(Z, gamma) = (1 + a exp(b / cos Z)) (1 + c exp(d gamma) + e cos^2 gamma)

but its five parameters follow the sky's state rather than one of 15 fixed types: each is
``x1 + x2 Zs + Delta (x3 + x4 Zs)`` (``Zs`` the sun's zenith angle in radians) with the
coefficients of the paper's Table 1 for one of eight bins of the sky clearness ``epsilon``
(``PEREZ_1993``; the first bin's ``c`` and ``d`` have their own forms, the paper's equations 7
and 8), and ``Delta`` the sky brightness ``DHI * m / E0`` (air mass ``m``, extraterrestrial
irradiance ``E0``). The scene estimate measures ``epsilon`` and ``Delta`` from its own sun and
sky (their ratio and the sky's irradiance), so the clear sky's shape follows the estimate; the
CIE clear sky (type 12) is one fixed shape, and under the all-weather clear sky the shaded
north wall of the demo's visitor centre got 0.56-0.60 of the horizontal irradiance where the
CIE clear sky gave it 0.47-0.54 (docs/server.md).

Directions are site-frame unit vectors (+X east, +Y up, -Z north).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pvlib

SOLAR_CONSTANT_W_M2 = 1367.0  # E0 without the year's +-3.4 %: the estimate knows no date
# Lower edges of Perez's eight clearness bins (the last open above)
CLEARNESS_BIN_EDGES = (1.0, 1.065, 1.230, 1.500, 1.950, 2.800, 4.500, 6.200)
# Table 1 of Perez, Seals & Michalsky (1993): per clearness bin, for a, b, c, d, e the four
# coefficients (x1, x2, x3, x4) of x = x1 + x2 Zs + Delta (x3 + x4 Zs)
PEREZ_1993 = np.array([
    [[1.3525, -0.2576, -0.2690, -1.4366], [-0.7670, 0.0007, 1.2734, -0.1233],
     [2.8000, 0.6004, 1.2375, 1.0000], [1.8734, 0.6297, 0.9738, 0.2809],
     [0.0356, -0.1246, -0.5718, 0.9938]],
    [[-1.2219, -0.7730, 1.4148, 1.1016], [-0.2054, 0.0367, -3.9128, 0.9156],
     [6.9750, 0.1774, 6.4477, -0.1239], [-1.5798, -0.5081, -1.7812, 0.1080],
     [0.2624, 0.0672, -0.2190, -0.4285]],
    [[-1.1000, -0.2515, 0.8952, 0.0156], [0.2782, -0.1812, -4.5000, 1.1766],
     [24.7219, -13.0812, -37.7000, 34.8438], [-5.0000, 1.5218, 3.9229, -2.6204],
     [-0.0156, 0.1597, 0.4199, -0.5562]],
    [[-0.5484, -0.6654, -0.2672, 0.7117], [0.7234, -0.6219, -5.6812, 2.6297],
     [33.3389, -18.3000, -62.2500, 52.0781], [-3.5000, 0.0016, 1.1477, 0.1062],
     [0.4659, -0.3296, -0.0876, -0.0329]],
    [[-0.6000, -0.3566, -2.5000, 2.3250], [0.2937, 0.0496, -5.6812, 1.8415],
     [21.0000, -4.7656, -21.5906, 7.2492], [-3.5000, -0.1554, 1.4062, 0.3988],
     [0.0032, 0.0766, -0.0656, -0.1294]],
    [[-1.0156, -0.3670, 1.0078, 1.4051], [0.2875, -0.5328, -3.8500, 3.3750],
     [14.0000, -0.9999, -7.1406, 7.5469], [-3.4000, -0.1078, -1.0750, 1.5702],
     [-0.0672, 0.4016, 0.3017, -0.4844]],
    [[-1.0000, 0.0211, 0.5025, -0.5119], [-0.3000, 0.1922, 0.7023, -1.6317],
     [19.0000, -5.0000, 1.2438, -1.9094], [-4.0000, 0.0250, 0.3844, 0.2656],
     [1.0468, -0.3788, -2.4517, 1.4656]],
    [[-1.0500, 0.0289, 0.4260, 0.3590], [-0.3250, 0.1156, 0.7781, 0.0025],
     [31.0625, -14.5000, -46.1148, 55.3750], [-7.2312, 0.4050, 13.3500, 0.6234],
     [1.5000, -0.6426, 1.8564, 0.5636]],
])


def air_mass(sun_elevation_deg: float) -> float:
    """Kasten & Young's (1989) relative optical air mass (pvlib's; 38 at the horizon)."""
    zenith_deg = 90.0 - min(max(sun_elevation_deg, 0.0), 90.0)
    return float(pvlib.atmosphere.get_relative_airmass(zenith_deg, model="kastenyoung1989"))


def sky_brightness(sky_horizontal_w_m2: float, sun_elevation_deg: float) -> float:
    """Perez's sky brightness ``Delta = DHI * m / E0`` (at least 0.01, the model's range)."""
    return max(sky_horizontal_w_m2 * air_mass(sun_elevation_deg) / SOLAR_CONSTANT_W_M2, 0.01)


def _bin(clearness: float) -> int:
    k = int(np.searchsorted(CLEARNESS_BIN_EDGES, clearness, side="right")) - 1
    return min(max(k, 0), len(PEREZ_1993) - 1)


def perez_parameters(clearness: float, brightness: float, sun_zenith_rad: float,
                     clear_bin: int | None = None) -> tuple[float, float, float, float, float]:
    """The all-weather sky's (a, b, c, d, e) for a clearness ``epsilon`` (or the clearness
    bin ``clear_bin``, 0-7), a brightness ``Delta`` and the sun's zenith angle (radians)."""
    k = _bin(clearness) if clear_bin is None else clear_bin
    t = PEREZ_1993[k]
    z = sun_zenith_rad
    a, b, c, d, e = (float(x[0] + x[1] * z + brightness * (x[2] + x[3] * z)) for x in t)
    if k == 0:  # the overcast bin: the paper's equations 7 and 8
        c = math.exp((brightness * (t[2][0] + t[2][1] * z)) ** t[2][2]) - t[2][3]
        d = -math.exp(brightness * (t[3][0] + t[3][1] * z)) + t[3][2] + brightness * t[3][3]
    return a, b, c, d, e


@dataclass
class PerezShape:
    """The all-weather sky's relative luminance for one state, 1 at the zenith (the
    ``relative_luminance`` of ``daylit.sky.CIESky``, which :func:`server.skyshape.unit_sky`
    scales). ``sun_dir`` (3,) unit, site frame."""

    clearness: float
    brightness: float
    sun_dir: np.ndarray

    def __post_init__(self):
        self.sun_dir = np.asarray(self.sun_dir, float)
        self.sun_zenith_rad = math.acos(min(max(float(self.sun_dir[1]), 0.0), 1.0))
        # (the parameters jump at the bins' edges: a blend of the two bins' shapes within
        # 10 % of an edge read the tests' small site's clear sky 14:30 sky 8-12 % low, where
        # the published bins alone read it 5-8 % low)
        self.params = perez_parameters(self.clearness, self.brightness, self.sun_zenith_rad)

    @staticmethod
    def _lv(params, cos_zenith: np.ndarray, gamma: np.ndarray) -> np.ndarray:
        a, b, c, d, e = params
        return (1.0 + a * np.exp(b / cos_zenith)) * (1.0 + c * np.exp(d * gamma)
                                                     + e * np.cos(gamma) ** 2)

    def relative_luminance(self, dirs: np.ndarray) -> np.ndarray:
        """(m,) for unit directions (m, 3), 1 at the zenith (the horizon's value below it;
        callers keep to the upper hemisphere), never negative."""
        cos_z = np.clip(dirs[:, 1], 1e-2, 1.0)
        gamma = np.arccos(np.clip(dirs @ self.sun_dir, -1.0, 1.0))
        zenith = self._lv(self.params, np.ones(1), np.array([self.sun_zenith_rad]))[0]
        return np.clip(self._lv(self.params, cos_z, gamma) / max(zenith, 1e-9), 0.0, None)

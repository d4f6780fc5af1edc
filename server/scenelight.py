"""One scene estimate's result (server.sceneestimate): the sun's and the sky's RGB irradiance,
the sky's shape, and the estimate as a ``daylit.sky.Sky``.

Directions are site-frame unit vectors (+X east, +Y up, -Z north); irradiances W/m^2;
radiances W/(m^2 sr).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from daylit.sky import SUN_SOLID_ANGLE_SR, Sky, Sun
from server.skyshape import unit_sky

LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])
# The sky's relative standard error (SceneLight.sky_uncertainty) above which the view is said
# not to separate the sky from the sun. On the demo's kiosk view (320x180, clear sky, noise,
# JPEG 85) it was 0.014-0.024 where 179-245 shaded pixels read the sky, and 0.036-0.065 at
# 9:30 with 17, where the sky's errors reached +10 to +15 % (docs/server.md).
SKY_UNCERTAIN = 0.03


@dataclass
class SceneLight:
    """One estimate.

    sun_normal_irradiance : (3,) RGB W/m^2 (0 when the sun is down or unseen)
    sky_horizontal_irradiance : (3,) RGB W/m^2 of an open horizontal plane, sun excluded
    sky_type : the CIE general sky the shape was taken from
    sun_direction : (3,) unit site direction
    sun_observable : False when too few usable samples were in sun to tell the sun from the sky
    used : samples that entered the solve; inlier_fraction : of them, weight > 0.5
    model_share : the model sky's share of the sky irradiance; the rest is isotropic
    perez : (clearness, brightness) of the Perez all-weather sky that gave the shape (under a
        clear sky, ``server.perezsky``), or None: the CIE sky of ``sky_type``
    shaded : of ``used``, the samples wholly in the model's shadow (what tells the sky from
        the sun; few, and a clear sky's estimate is the sky model's guess)
    sky_uncertainty : the sky's relative standard error from the fit's own residuals (on the
        channel sum; inf when the sky is not determined): above ``SKY_UNCERTAIN`` the view
        cannot tell this sky from the sun (``sky_separable``)
    """

    sun_normal_irradiance: np.ndarray
    sky_horizontal_irradiance: np.ndarray
    sky_type: int
    sun_direction: np.ndarray
    sun_observable: bool
    used: int
    inlier_fraction: float
    model_share: float = 1.0
    perez: tuple[float, float] | None = None
    shaded: int = 0
    sky_uncertainty: float = 0.0

    @property
    def sky_separable(self) -> bool:
        """Whether the frame's samples tell this sky from the sun (``sky_uncertainty`` at most
        ``SKY_UNCERTAIN``); when not, the sky (and with it the sun) is the fit's best guess on
        a view with too little shade."""
        return self.sky_uncertainty <= SKY_UNCERTAIN

    def sky(self) -> EstimatedSky:
        """The estimated sky (a ``daylit.sky.Sky``: radiance over directions, and the sun)."""
        return EstimatedSky(self)


class EstimatedSky(Sky):
    """A :class:`SceneLight` as a sky: ``model_share`` of the CIE sky of its type plus the
    rest uniform, scaled per channel to the estimated horizontal irradiance; the sun a disc of
    the estimated normal irradiance (none when it is 0)."""

    def __init__(self, light: SceneLight):
        self.light = light
        self._shape, self._to_unit = unit_sky(light.sky_type, light.sun_direction,
                                              light.perez)
        e_sun = np.asarray(light.sun_normal_irradiance, float)
        self.sun = Sun(light.sun_direction, e_sun / SUN_SOLID_ANGLE_SR) \
            if e_sun.max() > 0.0 and light.sun_direction[1] > 0.0 else None

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        share = self.light.model_share
        rel = share * self._shape.relative_luminance(dirs) * self._to_unit + (1.0 - share) / \
            math.pi
        out = rel[:, None] * np.asarray(self.light.sky_horizontal_irradiance, float)[None]
        out[dirs[:, 1] < 0.0] = 0.0
        return out


"""The simulated sky's clouds: a drifting deck (:class:`CloudLayer`) over a clear CIE sky, and
the sky they make at one instant (:class:`CloudySky`, a ``daylit.sky.Sky``) with the sun
dimmed where a cloud covers it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import ndimage

from daylit.sky import CIESky, Sky, Sun


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

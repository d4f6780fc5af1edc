"""The sky camera's sky checked against the site's own pixels (issue 16: drift detection).

A sky camera that drifts (its gain changes, its lens fogs or gets dirty) reads the whole sky
low or high by a factor. Comparing its horizontal irradiance with the scene estimate's
(:mod:`server.fusion`'s ``sky_ratio``) cannot see a drift under about 25 %: the estimate's sky
is a CIE model's shape, and against real skies its brightness is off by 5-30 % depending on the
weather (the circumsolar sky of a partly cloudy day taken for sun).

Here the sky camera's *measured* sky is the shape instead. Each sample of the scene estimate
(:class:`server.sceneestimate.SceneEstimator`: a pixel of a known surface, its albedo, normal,
whether it is in sun, the directions its hemisphere sees open sky) then has the model

    L = rho / pi * (E_sun * (cos_i * in_sun + B_sun)  +  g * (T_cam + B_cam))

with ``T_cam`` the irradiance the sky camera's patch radiances give over the directions the
point sees open sky, ``B_cam`` the one bounce (each surface the point sees instead, lit by the
sky camera's sky on its own tilt, unobstructed: the sky's spherical harmonics to l = 2, as
:func:`server.skyshape.tilted_irradiance`), ``E_sun`` free (the camera's disc clips), and one
unknown ``g``: what the site's pixels say the sky camera's sky must be multiplied by. A right
sky camera gives ``g`` near 1 whatever the weather; a camera reading the sky at ``f`` of its
true brightness gives ``1 / f``. :func:`sky_camera_gain` returns ``f = 1 / g`` (sky camera
over the site).
Patches the sky camera clipped (the sun's surroundings) read low; the free sun takes that up.
"""

from __future__ import annotations

import math

import numpy as np

from daylit.spherical import PatchLookup, normalize, patch_sh9, sh9_basis
from server.robustfit import ransac_fit, robust_linear_fit
from server.sceneestimate import SceneEstimateError, SceneEstimator
from server.skyshape import SH9_COSINE


class SkyPatches:
    """Which dome patch each hemisphere direction of an estimator's sample pool falls in.

    dome_vertices : (n, 3, 3) the build's dome patches (the sky camera's light vector's)
    """

    def __init__(self, estimator: SceneEstimator, dome_vertices: np.ndarray):
        pool = estimator.pool_samples
        hemi = pool.hemisphere_dirs
        self.patch = PatchLookup(np.asarray(dome_vertices, float))(
            hemi.reshape(-1, 3)).reshape(hemi.shape[:2])  # (m, K) int
        self.estimator = estimator
        self.patch_sh9 = patch_sh9(np.asarray(dome_vertices, float), 8)  # (n, 9)
        self.bounce_sh9 = sh9_basis(pool.bounce_normals)  # (b, 9)

    def bounce_sky(self, grey_radiance: np.ndarray) -> np.ndarray:
        """(m, 3) each pool sample's one bounce, W/m^2 per unit albedo of its own, from
        patch radiances (n,): the bounce surfaces lit by that sky on their tilts."""
        coeff = SH9_COSINE * (grey_radiance @ self.patch_sh9)
        tilt = np.clip(self.bounce_sh9 @ coeff, 0.0, None)
        pool = self.estimator.pool_samples
        return pool.bounce_terms(np.zeros(len(tilt)), tilt)[1]


def sky_camera_gain(patches: SkyPatches, image: np.ndarray, sun_dir: np.ndarray,
                    patch_radiance: np.ndarray, sky_horizontal_w_m2: float,
                    radiance_per_unit: float = 1.0, clip_level: float | None = None,
                    to_linear=None) -> float:
    """The sky camera's sky over what the site's pixels say it is (grey; 1: they agree).

    image : (H, W, 3) a frame of the estimator's view (linear, or codes with ``to_linear``);
    sun_dir : (3,) unit site direction of the sun; patch_radiance : (n, 3) the sky camera's
    patch radiances W/(m^2 sr); sky_horizontal_w_m2 : their horizontal irradiance (grey).
    Samples are picked and read as by :meth:`SceneEstimator.estimate`, with the surfaces'
    learned albedo scales. :class:`SceneEstimateError` when the frame cannot tell.
    """
    est = patches.estimator
    if est._rng is None:
        est._rng = np.random.default_rng(est.seed + 2)
    p = est.pool_samples
    sun_dir = normalize(np.asarray(sun_dir, float))
    lit, bounce_sun, _ = est.in_sun(sun_dir)
    pick = est._pick(lit)
    xy = p.pixels_xy[pick]
    values = est.read_pixels(image, xy, to_linear)
    usable = np.all(np.isfinite(values), axis=(0, 2)) & (values.min(axis=(0, 2)) >= 0.0)
    if clip_level is not None:
        usable &= values.max(axis=(0, 2)) < clip_level
    pick, y = pick[usable], values.mean(axis=0)[usable] * radiance_per_unit
    if len(pick) < 8 or sky_horizontal_w_m2 <= 0.0:
        raise SceneEstimateError(f"only {len(pick)} usable samples, or no sky")
    grey = np.asarray(patch_radiance, float).mean(axis=1)  # (n,)
    # the sky camera's sky over the open directions of each sample: (s,) W/m^2
    t_cam = math.pi * np.mean(grey[patches.patch[pick]] * p.sky_visible[pick], axis=1)
    albedo = p.albedo[pick] * est._scales.of(p.surface[pick])[:, None]
    cos_i = np.clip(p.normals[pick] @ sun_dir, 0.0, None) * lit[pick]
    sun_col = (albedo * (cos_i[:, None] + bounce_sun[pick])).sum(axis=1) / math.pi
    sky_col = (albedo * (t_cam[:, None] + patches.bounce_sky(grey)[pick])).sum(
        axis=1) / math.pi
    y_sum = y.sum(axis=1)
    inliers = ransac_fit(sun_col, sky_col, y_sum, est._rng)
    x, _ = robust_linear_fit(np.column_stack([sun_col, sky_col]), y_sum, inliers)
    if x[1] <= 0.0:
        raise SceneEstimateError("the site's pixels leave no sky to compare")
    return float(1.0 / x[1])

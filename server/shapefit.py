"""The scene estimate's solve for one sky shape (server.sceneestimate): the sun and the sky's
scale per RGB channel, robustly, with the sky's angular distribution of a CIE type or of
Perez's all-weather sky, and the choice between the overcast shapes.

The model and its terms are described in ``server/sceneestimate.py``. :class:`ShapeFits` is a
mixin of :class:`server.sceneestimate.SceneEstimator`: it uses the estimator's settings
(``learn_albedo``, ``share_memory``, ``sun_significance``), its ``sky_term``, its surfaces'
albedo scales and its random generator, and keeps the state followed across frames (the
model share, the overcast shapes' misfit).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from server.perezsky import sky_brightness
from server.robustfit import ransac_fit, robust_linear_fit, weighted_nonneg
from server.scenelight import LUMINANCE_RGB, SceneLight
from server.skyshape import OVERCAST_TYPES, sky_clearness

MIN_SUNLIT = 10  # fewer usable sunlit samples: the sun cannot be told from the sky


@dataclass
class FrameSamples:
    """One frame's usable samples: pool indices ``pick`` (n0,) and indices ``shade_pick`` (n1,)
    into the shade samples of the sun (``SceneEstimator.shade_samples``), n = n0 + n1, in that
    order; linear radiances ``values`` (n, 3) W/(m^2 sr), and the terms for them: ``cos_i``
    (n,) the sun's cosine where in sun (else 0), ``bounce_sun`` and ``bounce_sky`` (n, 3),
    stated ``albedo`` (n, 3), ``surface`` (n,) int and ``sky_view`` (n,)."""

    pick: np.ndarray
    values: np.ndarray
    cos_i: np.ndarray
    bounce_sun: np.ndarray
    bounce_sky: np.ndarray
    albedo: np.ndarray
    surface: np.ndarray
    sky_view: np.ndarray
    shade_pick: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


def perez_state(light: SceneLight, sun_elevation_deg: float) -> tuple[float, float]:
    """(clearness, brightness) of the Perez all-weather sky for an estimate's sun and sky
    (luminance-weighted grey; W/m^2 for a camera whose ``radiance_per_unit`` is absolute),
    rounded so that a state that barely moved reuses the cached sky term."""
    sky = max(float(LUMINANCE_RGB @ light.sky_horizontal_irradiance), 1e-9)
    sun = float(LUMINANCE_RGB @ light.sun_normal_irradiance)
    return (round(sky_clearness(sun / sky, sun_elevation_deg), 2),
            round(sky_brightness(sky, sun_elevation_deg), 3))


def _weighted_mse(values: np.ndarray, model: np.ndarray, weights: np.ndarray) -> float:
    """The weighted mean of squared residuals (n,): comparable between fits whose robust
    weights differ."""
    return float(weights @ (values - model) ** 2) / max(float(weights.sum()), 1e-12)


def _albedo_terms(albedo: np.ndarray, per_albedo: list[np.ndarray]):
    """The fit's terms for the samples' albedos (n, 3): each of ``per_albedo``'s (n, 3)
    radiances per unit light and albedo times the albedo, and (n, 3) their channel sums as
    the columns of the fit over the channel sum."""
    terms = [albedo * t for t in per_albedo]
    return terms, np.column_stack([t.sum(axis=1) for t in terms])


class ShapeFits:
    """The fits of :class:`server.sceneestimate.SceneEstimator` for one sky shape (a mixin)."""

    def _model_share(self, sky_type: int | str, x_sum: np.ndarray) -> float:
        """The sky's shape, the model's share against the isotropic part, from a fit ``x_sum``
        (sun, model sky, isotropic sky) of the channel sum; per channel only the sun and the
        sky's scale are solved. The share is poorly determined by one frame's samples (the two
        columns are nearly collinear) and the sky's shape changes slowly: it is followed across
        frames (kept by :meth:`estimate`). The Perez sky (key ``"perez"``) is taken whole,
        share 1: its shape follows the measured clearness and brightness, and the isotropic
        part that made up for the CIE clear sky's one fixed shape put the demo's visitor
        centre view's clear sky 3-9 % low in every stream, against 0-7 % low taken whole."""
        if sky_type == "perez":
            return 1.0
        share = x_sum[1] / max(x_sum[1] + x_sum[2], 1e-12) if x_sum[1:].sum() > 0 else 1.0
        previous = self._share.get(sky_type)
        return float(share if previous is None else (
            self.share_memory * previous + (1.0 - self.share_memory) * share))

    def _best_overcast_fit(self, sun_dir: np.ndarray, frame: FrameSamples,
                           allow_sun: bool = True) -> SceneLight:
        """The overcast shape that explains the frames best without a sun (the sky-alone
        residual, followed across frames), fitted with it; the surfaces' albedo scales as that
        fit left them (each shape's fit starts from the same scales: one shape's refit must
        not steer the other's)."""
        before = copy.deepcopy(self._surface_scales)
        fits = []
        for sky_type in OVERCAST_TYPES:
            self._surface_scales = copy.deepcopy(before)
            light, sky_alone = self._fit_shape(sky_type, sun_dir, frame, allow_sun)
            # followed across frames like the share: the sky's shape changes slowly, one
            # frame's residuals are noisy
            previous = self._shape_misfit.get(sky_type, sky_alone)
            self._shape_misfit[sky_type] = (self.share_memory * previous
                                            + (1.0 - self.share_memory) * sky_alone)
            fits.append((self._shape_misfit[sky_type], light, self._surface_scales))
        _, light, self._surface_scales = min(fits, key=lambda fit: fit[0])
        return light

    def _fit_shape(self, sky_type: int, sun_dir: np.ndarray, frame: FrameSamples,
                   allow_sun: bool = True, perez: tuple[float, float] | None = None
                   ) -> tuple[SceneLight, float]:
        """The sun and sky with the sky's shape of CIE type ``sky_type``, and the weighted
        mean squared residual the sky alone leaves with that shape (what tells one overcast
        shape from another)."""
        s, b_model = self.frame_sky_term(sky_type, sun_dir, frame, perez)
        share_key = sky_type if perez is None else "perez"
        values = frame.values
        y_sum = values.sum(axis=1)
        # (n, 3): radiance per unit sun normal irradiance and albedo, per unit sky irradiance
        # and albedo; the last the isotropic part of the sky: what a uniform sky of unit
        # horizontal irradiance gives (the sky view factor; Perez and Hay-Davies split the sky
        # the same way)
        per_albedo = [(frame.cos_i[:, None] + frame.bounce_sun) / math.pi,
                      (s[:, None] + b_model) / math.pi,
                      (frame.sky_view[:, None] + frame.bounce_sky) / math.pi]
        sunlit_count = int(np.sum(frame.cos_i > 0.05))
        if sunlit_count < MIN_SUNLIT:
            per_albedo[0] = np.zeros_like(per_albedo[0])
        stated_albedo, surface = frame.albedo, frame.surface
        (a_rgb, c_rgb, u_rgb), A_sum = _albedo_terms(
            stated_albedo * self._scales.of(surface)[:, None], per_albedo)
        inliers = ransac_fit(A_sum[:, 0], A_sum[:, 1], y_sum, self._rng)
        # The shade samples are single dark pixels (server.shadepool), 10-30 % noise each
        # through a JPEG where a patch in sun has 1-2 %: they start as inliers and have their
        # own residual scale. Judged on the sunlit patches' scale nearly all were dropped and
        # the few kept set the sky (up to +40 % on the demo's kiosk view).
        groups = np.zeros(len(y_sum), int)
        groups[len(frame.pick):] = 1
        inliers = inliers | (groups == 1)
        # The weights come from the channel sum (a person in a red coat is an outlier in
        # every channel); each channel is then one weighted least-squares solve.
        x_sum, weights = robust_linear_fit(A_sum, y_sum, inliers, groups=groups)
        if self.learn_albedo:
            # a wrong albedo on one surface: its scale from these samples, then the fit
            # again with it. The sky as one term of this fit's shape: the model and the
            # isotropic sky differ most on walls, and two free sky terms would let a
            # wall's scale take up the difference.
            share = self._model_share(share_key, x_sum)
            sun_t = (stated_albedo * per_albedo[0]).sum(axis=1)
            sky_t = (stated_albedo * (share * per_albedo[1] + (1.0 - share) * per_albedo[2]))
            self._scales.refit(surface, np.column_stack([sun_t, sky_t.sum(axis=1)]), y_sum)
            (a_rgb, c_rgb, u_rgb), A_sum = _albedo_terms(
                stated_albedo * self._scales.of(surface)[:, None], per_albedo)
            x_sum, weights = robust_linear_fit(A_sum, y_sum, weights, groups=groups)
        model_share = self._model_share(share_key, x_sum)
        sky_col = model_share * c_rgb + (1.0 - model_share) * u_rgb
        sun_rgb, sky_rgb, with_sun = np.zeros(3), np.zeros(3), 0.0
        sky_alone_rgb, sky_alone = np.zeros(3), 0.0
        for ch in range(3):
            both = np.column_stack([a_rgb[:, ch], sky_col[:, ch]])
            sun_rgb[ch], sky_rgb[ch] = weighted_nonneg(both, values[:, ch], weights)
            with_sun += _weighted_mse(values[:, ch], both @ [sun_rgb[ch], sky_rgb[ch]],
                                      weights)
            sky_alone_rgb[ch] = weighted_nonneg(sky_col[:, ch:ch + 1], values[:, ch],
                                                weights)[0]
            sky_alone += _weighted_mse(values[:, ch], sky_alone_rgb[ch] * sky_col[:, ch],
                                       weights)
        sun_needed = with_sun < (1.0 - self.sun_significance) * sky_alone
        if not allow_sun or not sun_needed:
            # A sun that explains little more than the sky alone is the sky model's error or
            # noise, not a sun (Jensen et al.: under heavy cloud, none). Under every type: a
            # view with almost no shade (the demo's kiosk: a tree's thin shadow) went from the
            # clear type to an intermediate one on noise and kept a sun of up to 94 % of an
            # overcast sky there; the estimate then falls to an overcast type.
            sun_rgb, sky_rgb = np.zeros(3), sky_alone_rgb
        columns = [sky_col.sum(axis=1)] if not sun_rgb.any() else [a_rgb.sum(axis=1),
                                                                    sky_col.sum(axis=1)]
        self._share[share_key] = model_share
        return (SceneLight(sun_rgb, sky_rgb, sky_type, sun_dir, sunlit_count >= MIN_SUNLIT,
                           len(frame.values), float(np.mean(weights > 0.5)),
                           float(model_share), perez, int(np.sum(frame.cos_i <= 0.0)),
                           _sky_uncertainty(np.column_stack(columns), y_sum, weights)),
                sky_alone)


def _sky_uncertainty(A: np.ndarray, y: np.ndarray, weights: np.ndarray) -> float:
    """The relative standard error of the last unknown (the sky) of the weighted fit
    ``y ~ A x`` (A (n, p), y (n,), weights (n,)): the sandwich (heteroscedasticity-consistent,
    HC0) covariance, since single shaded pixels and sunlit patches differ in noise. inf when
    the sky is not determined (no sky, or the columns collinear)."""
    x = weighted_nonneg(A, y, weights)
    if x[-1] <= 0.0:
        return math.inf
    r = y - A @ x
    bread = A.T @ (weights[:, None] * A)
    score = A * (weights * r)[:, None]
    meat = score.T @ score
    try:
        inv = np.linalg.inv(bread)
    except np.linalg.LinAlgError:
        return math.inf
    var = float((inv @ meat @ inv)[-1, -1])
    return math.sqrt(max(var, 0.0)) / float(x[-1])

"""Sun and sky estimated from what a camera sees of the site (Jensen, Andersen & Madsen 2006).

A Lambertian surface of albedo ``rho`` (RGB) seen by a camera has the radiance

    L = rho / pi * (E_sun * (cos_i * in_sun + B_sun)  +  k * (S + B_sky))

with ``E_sun`` the sun's normal irradiance, ``cos_i`` the cosine between the surface normal and
the sun, ``in_sun`` whether the sun is unobstructed from the point (a ray cast against the real
proxies), ``k`` the sky's diffuse horizontal irradiance, ``S`` the sky's irradiance on the
surface per unit of ``k`` (the model sky's relative radiance over the directions the point sees
open sky, normalised so that an open horizontal plane gets 1). ``B_sun`` and ``B_sky`` are one
bounce: over the directions the point sees another surface ``h`` (cosine-weighted mean, per
channel), ``rho_h cos_h in_sun_h`` and ``rho_h E(n_h)`` (the surface lit by the sun where it
is in sun, and by the model sky on its own tilt, unobstructed: :func:`tilted_irradiance`, for
the isotropic part ``(1 + n_h.up) / 2``); directions below the horizon that hit nothing count
as open, sunlit ground of ``environment_albedo``.
The model is linear in ``(E_sun, k)`` per RGB channel; a few hundred pixels of known surfaces,
some in sun and some in shadow, determine both. People, wet patches, a wrong albedo and shadows
the model does not know are outliers: the solve is robust (RANSAC on the channel sum, then
iteratively reweighted least squares with Tukey's biweight on relative residuals, per channel).
Under heavy cloud sunlit and shadowed surfaces look alike and ``E_sun`` goes to about 0.

The sky's angular distribution is a CIE general sky (``daylit.sky.CIESky``) chosen by the
estimated sun/sky ratio (:func:`sky_type_for_ratio`) and solved again with that shape, blended
with an isotropic part whose share is fitted from the pixels (followed across frames); under a
clear sky then Perez's all-weather sky (``server.perezsky``) for the clearness and brightness
that fit measured, fitted once more and taken whole. A sample's open sky is found on a fixed
fine grid (``SceneSamples.sky_weight``), its bounce through its own jittered directions. Under any
sky the sun is kept only when it explains the pixels clearly better than the sky alone
(``sun_significance``; a view that shows almost no shade cannot tell a sun from the sky, and a
fit with a free sun there reads noise as one), and only when pairs of patches across the model's
shadow edges, which see nearly the same sky, show it (``pair_floor``,
``server/shadowpairs.py``). A sample's sun is the share of its patch in sun (a thin shadow seen
at a grazing angle is narrower than a patch). The overcast model's shape is what keeps the sun
near 0 under heavy cloud: anything the sky model gets wrong that differs between sunlit and
shadowed surfaces is read as sun. Radiance's Perez overcast skies are brighter toward the sun
when it is low and nearly uniform in azimuth when it is high; walls get about 0.4 of the
horizontal irradiance, not an isotropic sky's 0.5. So the overcast shape is either CIE type
(``OVERCAST_TYPES``: 1, uniform in azimuth, or 2, slight brightening toward the sun), whichever
leaves the smaller residual without a sun (followed across frames), and bounce surfaces are lit
on their tilt. Type 1 alone left a phantom sun at low sun; type 2 alone doubled the error of the
irradiance at the site's points under a high overcast sun (docs/benchmarks.md).

Everything that depends only on the view (pixels, their surface points, normals, albedos and
which hemisphere directions see open sky) is computed once by :class:`SceneSamples`
(``server/scenesamples.py``); what
depends on the sun (in sun or not) once per sun position (cached until it moves
``sun_cache_deg``); the per-frame cost is reading pixels and a small solve.

Directions are site-frame unit vectors (+X east, +Y up, -Z north); irradiances W/m^2; radiances
W/(m^2 sr). Cameras follow the manifest's views: 3x3 ``K`` (OpenCV: +X right, +Y down, +Z
forward, pixel centres at +0.5) and 4x4 ``world_from_camera``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np
import trimesh

from daylit.sky import SUN_SOLID_ANGLE_SR, Sky, Sun
from daylit.spherical import normalize
from server.perezsky import sky_brightness
from server.robustfit import ransac_fit, robust_linear_fit, weighted_nonneg
from server.scenesamples import (  # noqa: F401 (PinholeView, SceneEstimateError: the API)
    SURFACE_OFFSET_M,
    PinholeView,
    SceneEstimateError,
    SceneSamples,
    intersector,
    patch_points_m,
    prepare_samples,
)
from server.shadowpairs import ShadowPairs, pair_sun_ratio, shadow_pairs
from server.skyshape import (  # noqa: F401 (sky_type_for_ratio, unit_sky: used by tests)
    OVERCAST_TYPES,
    sky_clearness,
    sky_type_for_ratio,
    tilted_irradiance,
    unit_sky,
)
from server.surfacescale import SurfaceScales

LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])
MIN_SUNLIT = 10  # fewer usable sunlit samples: the sun cannot be told from the sky


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


@dataclass
class SceneEstimator:
    """Estimates the sun and sky from linear frames of one fixed view.

    Parameters
    ----------
    mesh : trimesh.Trimesh, the real proxies (and the ground) in site metres
    face_albedo : (F, 3) RGB albedo per face
    view : PinholeView
    environment_albedo : albedo of what a surface sees instead of the sky (one bounce)
    pool : how many candidate pixels to prepare; samples : how many each estimate uses
    patch_px : half-size of the square of pixels averaged per sample (1: 3 x 3)
    sun_cache_deg : in-sun flags are cast again when the sun moved more than this
    share_memory : weight of the past in the sky shape's model share (0: each frame alone)
    sun_significance : the sun is kept only if it lowers the weighted squared residual of the
        sky alone (same shape) by more than this fraction, under any sky type
    learn_albedo : learn each surface's albedo scale from the frames (server.surfacescale):
        one surface with a wrong stated albedo no longer scales the estimate
    perez_clear : under a clear sky, the sky's shape is the Perez all-weather sky for the
        measured clearness and brightness (``server.perezsky``), not the CIE clear sky
    pair_floor : a sun is dropped when the pairs across the model's shadow edges read less
        than this fraction of the sky's horizontal irradiance (server.shadowpairs; 0: no
        check)
    """

    mesh: trimesh.Trimesh
    face_albedo: np.ndarray
    view: PinholeView
    environment_albedo: float = 0.2
    pool: int = 3000
    samples: int = 500
    patch_px: int = 1
    seed: int = 0
    sun_cache_deg: float = 0.05
    hemisphere_count: int = 96
    share_memory: float = 0.8
    sun_significance: float = 0.5
    learn_albedo: bool = True
    pair_floor: float = 0.05
    perez_clear: bool = True
    _pool: SceneSamples | None = field(default=None, init=False, repr=False)
    _surface_scales: SurfaceScales | None = field(default=None, init=False, repr=False)
    _sun_cache: tuple | None = field(default=None, init=False, repr=False)
    _pairs_cache: tuple | None = field(default=None, init=False, repr=False)
    _patch_points: np.ndarray | None = field(default=None, init=False, repr=False)
    _rng: np.random.Generator | None = field(default=None, init=False, repr=False)
    _hit: object = field(default=None, init=False, repr=False)
    _sky_cache: dict = field(default_factory=dict, init=False, repr=False)
    _share: dict = field(default_factory=dict, init=False, repr=False)
    _shape_misfit: dict = field(default_factory=dict, init=False, repr=False)

    @property
    def pool_samples(self) -> SceneSamples:
        if self._pool is None:
            self._pool = prepare_samples(self.mesh, self.face_albedo, self.view, self.pool,
                                         self.hemisphere_count, self.seed,
                                         environment_albedo=self.environment_albedo)
        return self._pool

    @property
    def _scales(self) -> SurfaceScales:
        if self._surface_scales is None:
            self._surface_scales = SurfaceScales(self.pool_samples.surface)
        return self._surface_scales

    def surface_report(self) -> list[dict]:
        """Per surface (one stated albedo): its stated RGB albedo, share of the view's known
        pixels, the albedo scale learned from the frames and whether it is used (it is more
        than ``ALBEDO_TRUST`` off the stated albedo)."""
        p, scales = self.pool_samples, self._scales
        stated = np.zeros((len(scales.scale), 3))
        stated[p.surface] = p.albedo
        share = scales.area / max(float(scales.area.sum()), 1.0)
        return [{"albedo": [round(float(v), 4) for v in stated[k]],
                 "share_of_view": round(float(share[k]), 4),
                 "learned_scale": round(float(scales.scale[k]), 4),
                 "used": bool(scales.rescaled[k])}
                for k in range(len(scales.scale)) if scales.area[k] > 0]

    def in_sun(self, sun_dir: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For a sun direction: (m,) the share of each pool sample's patch of pixels that
        faces the sun with nothing of the mesh in between (0 to 1); (m, 3) and (m, 3), the
        bounce terms per unit sun normal irradiance and per unit sky irradiance
        (:meth:`SceneSamples.bounce_terms`). Cast again only when the sun moved more than
        ``sun_cache_deg``."""
        sun_dir = normalize(np.asarray(sun_dir, float))
        if self._sun_cache is not None and float(self._sun_cache[0] @ sun_dir) >= math.cos(
                math.radians(self.sun_cache_deg)):
            return self._sun_cache[1:]
        p = self.pool_samples
        # A sample reads its patch's mean, so its sun is the patch's share in sun: a thin
        # shadow seen at a grazing angle (a tree's on far ground) is a pixel or two wide, and
        # a patch centred in it reads mostly sunlit ground.
        points = self._patch_points_m()
        m, k = points.shape[:2]
        lit = self._unblocked(points.reshape(-1, 3), np.repeat(p.normals, k, axis=0),
                              sun_dir).reshape(m, k).mean(axis=1)
        cos_h = np.clip(p.bounce_normals @ sun_dir, 0.0, None)
        far = ~np.isfinite(p.bounce_points_m[:, 0])
        bounce = np.zeros(len(cos_h))
        near = ~far
        bounce[near] = cos_h[near] * self._unblocked(p.bounce_points_m[near],
                                                    p.bounce_normals[near], sun_dir)
        bounce[far] = cos_h[far] if sun_dir[1] > 0.0 else 0.0
        bounce_sun, bounce_sky, _ = p.bounce_terms(bounce)
        self._sun_cache = (sun_dir, lit, bounce_sun, bounce_sky)
        return lit, bounce_sun, bounce_sky

    def _patch_points_m(self) -> np.ndarray:
        """(m, P, 3): :func:`server.scenesamples.patch_points_m` of the pool, kept."""
        if self._patch_points is None:
            self._patch_points = patch_points_m(self.pool_samples, self.view, self.patch_px)
        return self._patch_points

    def shadow_pairs(self, sun_dir: np.ndarray) -> ShadowPairs:
        """The pool's pairs across the model's shadow edges for a sun direction
        (:func:`server.shadowpairs.shadow_pairs`), cached like :meth:`in_sun`."""
        sun_dir = normalize(np.asarray(sun_dir, float))
        if self._pairs_cache is not None and float(self._pairs_cache[0] @ sun_dir) >= math.cos(
                math.radians(self.sun_cache_deg)):
            return self._pairs_cache[1]
        p = self.pool_samples
        share = self.in_sun(sun_dir)[0]
        pairs = shadow_pairs(p.pixels_xy, p.points_m, p.normals, p.surface, p.sky_view, share,
                             sun_dir)
        self._pairs_cache = (sun_dir, pairs)
        return pairs

    def pair_sun_ratio(self, linear: np.ndarray, sun_dir: np.ndarray, light: SceneLight,
                       radiance_per_unit: float = 1.0, clip_level: float | None = None,
                       ignore_mask: np.ndarray | None = None, to_linear=None) -> float | None:
        """The sun the shadow-edge pairs read in a frame, over the sky's horizontal
        irradiance of ``light`` (:func:`server.shadowpairs.pair_sun_ratio`)."""
        return pair_sun_ratio(self, linear, sun_dir, light, radiance_per_unit, clip_level,
                              ignore_mask, to_linear)

    def sky_term(self, sky_type: int, sun_dir: np.ndarray,
                 perez: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """For a CIE sky of this type and sun scaled to an open horizontal irradiance of 1:
        (m,) each pool sample's irradiance from the open sky it sees, and (m, 3) its one
        bounce from the surfaces it sees instead, each lit by this sky on its own tilt
        (:func:`tilted_irradiance`; :meth:`SceneSamples.bounce_terms`). With ``perez``
        (clearness, brightness) the Perez all-weather sky of that state instead. Cached per
        sun position (and Perez state), like :meth:`in_sun`."""
        sun_dir = normalize(np.asarray(sun_dir, float))
        slot = sky_type if perez is None else "perez"
        key = self._sky_cache.get(slot)
        if key is not None and float(key[0] @ sun_dir) >= math.cos(
                math.radians(self.sun_cache_deg)) and key[3] == perez:
            return key[1], key[2]
        p = self.pool_samples
        shape, to_unit = unit_sky(sky_type, sun_dir, perez)
        # on the pool's sky grid, normalised on the same grid: an open horizontal plane gets 1
        rel = shape.relative_luminance(p.sky_grid_dirs)
        open_horizontal = float((p.sky_grid_dirs[:, 1] * p.sky_grid_sr) @ rel)
        term = (p.sky_weight @ rel.astype(np.float32)).astype(np.float64) / open_horizontal
        # (the bounce surfaces' own obstruction is left out, as for the isotropic part)
        tilt = np.clip(tilted_irradiance(shape, to_unit, p.bounce_normals), 0.0, None)
        bounce = p.bounce_terms(np.zeros(len(tilt)), tilt)[1]
        self._sky_cache[slot] = (sun_dir, term, bounce, perez)
        return term, bounce

    def _unblocked(self, points: np.ndarray, normals: np.ndarray, sun_dir: np.ndarray):
        """(m,) bool: the points face the sun, it is up, and no face of the mesh is between."""
        facing = normals @ sun_dir > 0.0
        lit = np.zeros(len(facing), bool)
        if sun_dir[1] > 0.0 and facing.any():
            idx = np.flatnonzero(facing)
            start = points[idx] + SURFACE_OFFSET_M * normals[idx]
            if self._hit is None:
                self._hit = intersector(self.mesh)
            lit[idx] = ~self._hit.intersects_any(start, np.broadcast_to(sun_dir, start.shape))
        return lit

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

    def _best_overcast_fit(self, sun_dir: np.ndarray, frame: _FrameSamples,
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

    def _fit_shape(self, sky_type: int, sun_dir: np.ndarray, frame: _FrameSamples,
                   allow_sun: bool = True, perez: tuple[float, float] | None = None
                   ) -> tuple[SceneLight, float]:
        """The sun and sky with the sky's shape of CIE type ``sky_type``, and the weighted
        mean squared residual the sky alone leaves with that shape (what tells one overcast
        shape from another)."""
        s, b_model = self.sky_term(sky_type, sun_dir, perez)
        share_key = sky_type if perez is None else "perez"
        s, b_model = s[frame.pick], b_model[frame.pick]
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
        # The weights come from the channel sum (a person in a red coat is an outlier in
        # every channel); each channel is then one weighted least-squares solve.
        x_sum, weights = robust_linear_fit(A_sum, y_sum, inliers)
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
            x_sum, weights = robust_linear_fit(A_sum, y_sum, weights)
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
        self._share[share_key] = model_share
        return SceneLight(sun_rgb, sky_rgb, sky_type, sun_dir, sunlit_count >= MIN_SUNLIT,
                          len(frame.pick), float(np.mean(weights > 0.5)),
                          float(model_share), perez), sky_alone

    def _pick(self, lit: np.ndarray) -> np.ndarray:
        """``samples`` pool indices, half mostly in sun and half mostly in shadow (``lit``,
        the share in sun, from 0.5 or below it) where the pool has them (the shadowed ones are
        what tells the sky from the sun)."""
        groups = [np.flatnonzero(lit >= 0.5), np.flatnonzero(lit < 0.5)]
        want = self.samples // 2
        small = min(groups, key=len)
        large = max(groups, key=len)
        take_small = min(len(small), want)
        take_large = min(len(large), self.samples - take_small)
        return np.concatenate([self._rng.choice(small, take_small, replace=False),
                               self._rng.choice(large, take_large, replace=False)])

    def read_pixels(self, image: np.ndarray, pixels_xy: np.ndarray,
                    to_linear=None) -> np.ndarray:
        """The ``(2 patch_px + 1)^2`` pixels about each pixel, (k, m, 3) linear RGB:
        ``image`` (H, W, >=3) as it is, or through ``to_linear`` (codes (..., 3) -> linear),
        which then runs on these pixels only, never on the whole frame."""
        r = self.patch_px
        dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
        ys = pixels_xy[None, :, 1] + dy.ravel()[:, None]
        xs = pixels_xy[None, :, 0] + dx.ravel()[:, None]
        raw = image[ys, xs, :3]
        return (to_linear(raw) if to_linear is not None else raw).astype(np.float64)

    def read_usable(self, image: np.ndarray, pixels_xy: np.ndarray, to_linear=None,
                    clip_level: float | None = None, ignore_mask: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Each sample's patch mean (m, 3) linear (:meth:`read_pixels`) and (m,) bool whether
        it is usable: finite, not negative, no pixel of its patch at ``clip_level``, not
        marked by ``ignore_mask`` (H, W bool)."""
        patches = self.read_pixels(image, pixels_xy, to_linear)
        values = patches.mean(axis=0)
        usable = np.all(np.isfinite(values), axis=1) & (values.min(axis=1) >= 0.0)
        if clip_level is not None:
            usable &= patches.max(axis=(0, 2)) < clip_level
        if ignore_mask is not None:
            usable &= ~np.asarray(ignore_mask, bool)[pixels_xy[:, 1], pixels_xy[:, 0]]
        return values, usable

    def estimate(self, linear: np.ndarray, sun_dir: np.ndarray, radiance_per_unit: float = 1.0,
                 clip_level: float | None = None, ignore_mask: np.ndarray | None = None,
                 to_linear=None) -> SceneLight:
        """One estimate from a frame (H, W, 3) of the view: linear RGB, or codes with
        ``to_linear`` (codes (..., 3) -> linear RGB; applied to the sampled pixels only).

        ``radiance_per_unit``: W/(m^2 sr) per linear unit (the camera's exposure and
        photometric factor). Samples any of whose pixels reach ``clip_level`` (linear), or
        that ``ignore_mask`` (H, W bool, e.g. visitors) marks, are skipped.
        """
        linear = np.asarray(linear)
        if linear.ndim != 3 or linear.shape[:2] != (self.view.height, self.view.width):
            raise SceneEstimateError(f"frame of shape {linear.shape}; the view is "
                                     f"{self.view.width}x{self.view.height}")
        if self._rng is None:
            self._rng = np.random.default_rng(self.seed + 2)
        sun_dir = normalize(np.asarray(sun_dir, float))
        p = self.pool_samples
        lit, bounce_sun, bounce_sky = self.in_sun(sun_dir)
        pick = self._pick(lit)
        xy = p.pixels_xy[pick]
        values, usable = self.read_usable(linear, xy, to_linear, clip_level, ignore_mask)
        pick, values = pick[usable], values[usable] * radiance_per_unit
        if len(pick) < 8:
            raise SceneEstimateError(f"only {len(pick)} usable samples in the frame")
        cos_i = np.clip(p.normals[pick] @ sun_dir, 0.0, None) * lit[pick]
        frame = _FrameSamples(pick, values, cos_i, bounce_sun[pick], bounce_sky[pick],
                              p.albedo[pick], p.surface[pick], p.sky_view[pick])
        sky_type = 12
        result = None
        sun_elevation_deg = math.degrees(math.asin(min(float(sun_dir[1]), 1.0)))
        for _ in range(3):
            if sky_type in OVERCAST_TYPES:
                result = self._best_overcast_fit(sun_dir, frame)
            else:
                result = self._fit_shape(sky_type, sun_dir, frame)[0]
            ratio = float(LUMINANCE_RGB @ result.sun_normal_irradiance) / max(
                float(LUMINANCE_RGB @ result.sky_horizontal_irradiance), 1e-9)
            new_type = sky_type_for_ratio(ratio, sun_elevation_deg)
            if new_type == sky_type:
                break
            sky_type = new_type
        if self.perez_clear and result.sky_type == 12 and result.sun_normal_irradiance.max() > 0:
            # the clear sky's shape from the Perez all-weather model for the state the CIE
            # clear sky's fit measured (its sun/sky ratio and the sky's irradiance), fitted
            # again with it, once: iterated, the state runs away (a sky read low raises the
            # clearness, whose shape reads the sky lower still: on the tests' small site at
            # 14:30 -8 to -12 % after one pass, -19 to -22 % after four)
            result = self._fit_shape(12, sun_dir, frame,
                                     perez=_perez_state(result, sun_elevation_deg))[0]
        if self.pair_floor > 0.0 and float(np.max(result.sun_normal_irradiance)) > 0.0:
            # the sky model's errors read as sun; the shadow edges alone say whether there is
            # one (server.shadowpairs)
            ratio = self.pair_sun_ratio(linear, sun_dir, result, radiance_per_unit, clip_level,
                                        ignore_mask, to_linear)
            if ratio is not None and ratio < self.pair_floor:
                result = self._best_overcast_fit(sun_dir, frame, allow_sun=False)
        if self.learn_albedo:
            self._scales.end_frame()
        return result


@dataclass
class _FrameSamples:
    """One frame's usable samples: pool indices ``pick`` (n,), linear radiances ``values``
    (n, 3) W/(m^2 sr), and the pool's terms for them: ``cos_i`` (n,) the sun's cosine where
    in sun (else 0), ``bounce_sun`` and ``bounce_sky`` (n, 3), stated ``albedo`` (n, 3),
    ``surface`` (n,) int and ``sky_view`` (n,)."""

    pick: np.ndarray
    values: np.ndarray
    cos_i: np.ndarray
    bounce_sun: np.ndarray
    bounce_sky: np.ndarray
    albedo: np.ndarray
    surface: np.ndarray
    sky_view: np.ndarray


def _perez_state(light: SceneLight, sun_elevation_deg: float) -> tuple[float, float]:
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

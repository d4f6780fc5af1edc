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

A view whose shade is too thin or broken for the pool's one-plane patches (fewer than half an
estimate's samples in shade) is topped up, per sun position, with single pixels wholly in the
model's shadow (``server/shadepool.py``), which the robust fit judges on their own residual
scale; the result's ``sky_uncertainty`` says how well the frame determined the sky.

The estimate's result is ``server/scenelight.py``'s :class:`SceneLight`; the solve for one sky
shape is ``server/shapefit.py``'s; which pixels a frame reads, ``server/framesampling.py``'s.

Directions are site-frame unit vectors (+X east, +Y up, -Z north); irradiances W/m^2; radiances
W/(m^2 sr). Cameras follow the manifest's views: 3x3 ``K`` (OpenCV: +X right, +Y down, +Z
forward, pixel centres at +0.5) and 4x4 ``world_from_camera``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh

from daylit.spherical import normalize
from server.framesampling import FrameSampling
from server.scenelight import (  # noqa: F401 (LUMINANCE_RGB, EstimatedSky: the API)
    LUMINANCE_RGB,
    EstimatedSky,
    SceneLight,
)
from server.scenesamples import (  # noqa: F401 (PinholeView, SceneEstimateError: the API)
    SURFACE_OFFSET_M,
    PinholeView,
    SceneEstimateError,
    SceneSamples,
    intersector,
    patch_points_m,
    prepare_samples,
    samples_at,
)
from server.shadepool import ViewHits, view_hits, wholly_shaded_pixels
from server.shadowpairs import ShadowPairs, pair_sun_ratio, shadow_pairs
from server.shapefit import FrameSamples, ShapeFits, perez_state
from server.skyshape import (  # noqa: F401 (sky_type_for_ratio, unit_sky: used by tests)
    OVERCAST_TYPES,
    sky_type_for_ratio,
    tilted_irradiance,
    unit_sky,
)
from server.surfacescale import SurfaceScales

# A shaded pixel's light is mostly the bounce from the sunlit ground it sees (about two
# thirds under the demo's tree at noon): its bounce is traced through this many times the
# pool's directions (there are at most ``samples`` of them). With the pool's 96, four pools
# read the kiosk view's noon sky +1 to +6 % on the render's own radiance; with 480, -1 to +3 %.
SHADE_HEMISPHERE_FACTOR = 5


@dataclass
class SceneEstimator(ShapeFits, FrameSampling):
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
    shade_top_up : when the pool has fewer than half of ``samples`` in shadow for the sun,
        up to that many single pixels wholly in the model's shadow are added to each
        estimate (``server.shadepool``; False: the pool alone)
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
    shade_top_up: bool = True
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
    _view_hits: ViewHits | None = field(default=None, init=False, repr=False)
    _shade_cache: tuple | None = field(default=None, init=False, repr=False)
    _shade_sky_cache: dict = field(default_factory=dict, init=False, repr=False)

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
        bounce_sun, bounce_sky = self._sun_bounce(p, sun_dir)
        self._sun_cache = (sun_dir, lit, bounce_sun, bounce_sky)
        return lit, bounce_sun, bounce_sky

    def _sun_bounce(self, p: SceneSamples, sun_dir: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """(m, 3) and (m, 3): the bounce terms of samples ``p`` per unit sun normal irradiance
        and per unit sky irradiance (:meth:`SceneSamples.bounce_terms`), each bounce point lit
        where the mesh does not shade it."""
        cos_h = np.clip(p.bounce_normals @ sun_dir, 0.0, None)
        far = ~np.isfinite(p.bounce_points_m[:, 0])
        bounce = np.zeros(len(cos_h))
        near = ~far
        bounce[near] = cos_h[near] * self._unblocked(p.bounce_points_m[near],
                                                    p.bounce_normals[near], sun_dir)
        bounce[far] = cos_h[far] if sun_dir[1] > 0.0 else 0.0
        bounce_sun, bounce_sky, _ = p.bounce_terms(bounce)
        return bounce_sun, bounce_sky

    def shade_samples(self, sun_dir: np.ndarray
                      ) -> tuple[SceneSamples | None, np.ndarray, np.ndarray]:
        """For a sun direction: the samples of pixels wholly in the model's shadow
        (:func:`server.shadepool.wholly_shaded_pixels`; up to ``samples`` of them, at random),
        or None when the view has none, and their bounce terms (k, 3) per unit sun normal
        irradiance and per unit sky irradiance. Cached like :meth:`in_sun`."""
        sun_dir = normalize(np.asarray(sun_dir, float))
        if self._shade_cache is not None and float(self._shade_cache[0] @ sun_dir) >= math.cos(
                math.radians(self.sun_cache_deg)):
            return self._shade_cache[1:]
        if self._hit is None:
            self._hit = intersector(self.mesh)
        if self._view_hits is None:
            self._view_hits = view_hits(self.mesh, self.view, self._hit)
        pixels = wholly_shaded_pixels(self._view_hits, self._hit, sun_dir)
        found: tuple = (None, np.zeros((0, 3)), np.zeros((0, 3)))
        if len(pixels):
            rng = np.random.default_rng(self.seed + 5)
            pixels = pixels[rng.choice(len(pixels), min(len(pixels), self.samples),
                                       replace=False)]
            shade = samples_at(self.mesh, self.face_albedo, self.view, pixels, self._hit,
                               SHADE_HEMISPHERE_FACTOR * self.hemisphere_count, self.seed + 5,
                               environment_albedo=self.environment_albedo)
            found = (shade, *self._sun_bounce(shade, sun_dir))
        self._shade_cache = (sun_dir, *found)
        self._shade_sky_cache.clear()
        return found

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
        term, bounce = _sky_term_of(self.pool_samples, sky_type, sun_dir, perez)
        self._sky_cache[slot] = (sun_dir, term, bounce, perez)
        return term, bounce

    def frame_sky_term(self, sky_type: int, sun_dir: np.ndarray, frame: FrameSamples,
                       perez: tuple[float, float] | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`sky_term` for a frame's samples: (n,) and (n, 3), the pool's picks then the
        shade samples' (:meth:`shade_samples` of the same sun)."""
        s, b = self.sky_term(sky_type, sun_dir, perez)
        if not len(frame.shade_pick):
            return s[frame.pick], b[frame.pick]
        shade = self._shade_cache[1]
        slot = (sky_type if perez is None else "perez", perez)
        if slot not in self._shade_sky_cache:
            self._shade_sky_cache[slot] = _sky_term_of(shade, sky_type,
                                                       self._shade_cache[0], perez)
        s_shade, b_shade = self._shade_sky_cache[slot]
        return (np.concatenate([s[frame.pick], s_shade[frame.shade_pick]]),
                np.vstack([b[frame.pick], b_shade[frame.shade_pick]]))

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
        # the pool's shade, topped up from pixels wholly in the model's shadow where it has
        # less than half the samples in shade (server.shadepool)
        top_up = 0
        shade, shade_sun, shade_sky = None, None, None
        pool_shaded = int(np.sum(lit < 0.5))
        if self.shade_top_up and pool_shaded < self.samples // 2:
            shade, shade_sun, shade_sky = self.shade_samples(sun_dir)
            top_up = 0 if shade is None else min(len(shade.pixels_xy),
                                                 self.samples // 2 - pool_shaded)
        pick = self._pick(lit, self.samples - top_up)
        values, usable = self.read_usable(linear, p.pixels_xy[pick], to_linear, clip_level,
                                          ignore_mask)
        pick, values = pick[usable], values[usable]
        cos_i = np.clip(p.normals[pick] @ sun_dir, 0.0, None) * lit[pick]
        terms = [cos_i, bounce_sun[pick], bounce_sky[pick], p.albedo[pick], p.surface[pick],
                 p.sky_view[pick]]
        shade_pick = np.zeros(0, int)
        if top_up:
            # single pixels: a wholly shaded pixel's neighbours may be other faces
            shade_pick = self._rng.choice(len(shade.pixels_xy), top_up, replace=False)
            shade_values, usable = self.read_usable(
                linear, shade.pixels_xy[shade_pick], to_linear, clip_level, ignore_mask,
                patch_px=0)
            shade_pick = shade_pick[usable]
            values = np.vstack([values, shade_values[usable]])
            more = [np.zeros(len(shade_pick)), shade_sun[shade_pick], shade_sky[shade_pick],
                    shade.albedo[shade_pick], shade.surface[shade_pick],
                    shade.sky_view[shade_pick]]
            terms = [np.concatenate([a, b]) for a, b in zip(terms, more, strict=True)]
        values = values * radiance_per_unit
        if len(values) < 8:
            raise SceneEstimateError(f"only {len(values)} usable samples in the frame")
        frame = FrameSamples(pick, values, *terms, shade_pick=shade_pick)
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
                                     perez=perez_state(result, sun_elevation_deg))[0]
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


def _sky_term_of(p: SceneSamples, sky_type: int, sun_dir: np.ndarray,
                 perez: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`SceneEstimator.sky_term` of samples ``p``, uncached: (m,) and (m, 3)."""
    shape, to_unit = unit_sky(sky_type, sun_dir, perez)
    # on the pool's sky grid, normalised on the same grid: an open horizontal plane gets 1
    rel = shape.relative_luminance(p.sky_grid_dirs)
    open_horizontal = float((p.sky_grid_dirs[:, 1] * p.sky_grid_sr) @ rel)
    term = (p.sky_weight @ rel.astype(np.float32)).astype(np.float64) / open_horizontal
    # (the bounce surfaces' own obstruction is left out, as for the isotropic part)
    normals, index = p.bounce_normal_groups
    tilt = np.clip(tilted_irradiance(shape, to_unit, normals), 0.0, None)[index]
    bounce = p.bounce_terms(np.zeros(len(tilt)), tilt)[1]
    return term, bounce

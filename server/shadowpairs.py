"""The sun read across shadow edges alone, as a check on the scene estimate (issue 16).

The scene estimate (``server/sceneestimate.py``) fits the sun and a model sky to every sampled
pixel at once. Under an overcast sky, whatever the sky model gets wrong that differs between
sunlit and shadowed surfaces is read as sun: on the demo's site, seen from a camera that was
not the one the estimator was tuned on, 3-11 of 40 overcast streams kept a sun of more than
5 % of the sky (docs/benchmarks.md, "On a site it was not tuned on").

Two patches of the same plane a few pixels apart, one wholly in the model's shadow and one
wholly in sun, see nearly the same sky: the difference of their radiances is the sun's, and the
sky model enters only through the small difference of their sky terms. Where there is no
shadow on the site (heavy cloud) these pairs say so whatever the model's shape. A pair is:

- a shaded patch of a surface that faces the sun (a cast shadow, not the surface's own back),
- a sunlit patch of the same surface and plane within ``radius_px`` pixels,
- whose sky views differ by at most ``max_sky_view_diff``.

A patch is all its pixels (the estimator reads a patch's mean); one that a shadow edge crosses
is neither shaded nor sunlit here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

MIN_PAIRS = 8  # fewer pairs: no check (the view shows too little shadow for it)
PAIR_SKY_TYPE = 2  # the CIE sky of the pairs' small sky differences (pair_sun_ratio)


@dataclass(frozen=True)
class ShadowPairs:
    """Pool indices of the pairs: ``shaded`` (P,) and ``lit`` (P,)."""

    shaded: np.ndarray
    lit: np.ndarray

    def __len__(self) -> int:
        return len(self.shaded)


def shadow_pairs(pixels_xy: np.ndarray, points_m: np.ndarray, normals: np.ndarray,
                 surface: np.ndarray, sky_view: np.ndarray, sun_share: np.ndarray,
                 sun_dir: np.ndarray, radius_px: float = 12.0, max_sky_view_diff: float = 0.1,
                 per_shaded: int = 3) -> ShadowPairs:
    """Pairs of pool samples across the model's shadow edges (see the module's docstring).

    pixels_xy (m, 2) pixel positions; points_m (m, 3) site points; normals (m, 3) unit;
    surface (m,) int surface ids; sky_view (m,) cosine-weighted open-sky fraction; sun_share
    (m,) the share of each patch's pixels in sun (0 to 1); sun_dir (3,) unit. Each shaded patch
    is paired with up to ``per_shaded`` of the nearest sunlit ones that qualify.
    """
    facing = normals @ np.asarray(sun_dir, float) > 0.05
    shaded = np.flatnonzero((sun_share == 0.0) & facing)
    lit = np.flatnonzero(sun_share == 1.0)
    if len(shaded) == 0 or len(lit) == 0:
        return ShadowPairs(np.zeros(0, int), np.zeros(0, int))
    tree = cKDTree(np.asarray(pixels_xy, float)[lit])
    k = min(len(lit), 4 * per_shaded)
    dist, near = tree.query(np.asarray(pixels_xy, float)[shaded], k=k,
                            distance_upper_bound=radius_px)
    dist, near = dist.reshape(len(shaded), k), near.reshape(len(shaded), k)
    out_shaded, out_lit = [], []
    for row, i in enumerate(shaded):
        found = near[row][np.isfinite(dist[row])]
        if len(found) == 0:
            continue
        j = lit[found]
        same = (surface[j] == surface[i]) & (normals[j] @ normals[i] > 0.999)
        same &= np.abs((points_m[j] - points_m[i]) @ normals[i]) < 0.02
        same &= np.abs(sky_view[j] - sky_view[i]) <= max_sky_view_diff
        j = j[same][:per_shaded]  # the query returns them nearest first
        out_shaded.extend([i] * len(j))
        out_lit.extend(j.tolist())
    return ShadowPairs(np.asarray(out_shaded, int), np.asarray(out_lit, int))


def pair_sun(radiance_shaded: np.ndarray, radiance_lit: np.ndarray,
             sky_shaded: np.ndarray, sky_lit: np.ndarray, sun_shaded: np.ndarray,
             sun_lit: np.ndarray) -> float:
    """The sun's normal irradiance (grey, W/m^2) the pairs read: the median over pairs of
    ``(L_lit - L_shaded - (sky_lit - sky_shaded)) / (sun_lit - sun_shaded)``, channels summed.

    radiance_* (P, 3) W/(m^2 sr) measured; sky_* (P, 3) the model sky's radiance at each
    sample (the fit's sky, its bounce included); sun_* (P, 3) radiance per unit sun normal
    irradiance (albedo / pi times the sun's cosine where in sun, plus its bounce).
    """
    contrast = (radiance_lit - radiance_shaded - (sky_lit - sky_shaded)).sum(axis=1)
    per_sun = (sun_lit - sun_shaded).sum(axis=1)
    ok = per_sun > 1e-9
    if not ok.any():
        return 0.0
    return float(np.median(contrast[ok] / per_sun[ok]))


def pair_sun_ratio(est, linear: np.ndarray, sun_dir: np.ndarray, light,
                   radiance_per_unit: float = 1.0, clip_level: float | None = None,
                   ignore_mask: np.ndarray | None = None, to_linear=None) -> float | None:
    """The sun a frame's shadow-edge pairs read (:func:`pair_sun`) over the sky's horizontal
    irradiance of ``light`` (a ``SceneLight``), for the estimator ``est``
    (``server.sceneestimate.SceneEstimator``: its pool, pairs, sun and sky terms and learned
    albedo scales); None with fewer than ``MIN_PAIRS`` usable pairs. Pixels are read and
    skipped as the estimate reads them (``SceneEstimator.read_usable``)."""
    pairs = est.shadow_pairs(sun_dir)
    if len(pairs) < MIN_PAIRS:
        return None
    p = est.pool_samples
    idx = np.unique(np.concatenate([pairs.shaded, pairs.lit]))
    values, usable = est.read_usable(linear, p.pixels_xy[idx], to_linear, clip_level,
                                     ignore_mask)
    row = np.full(len(p.pixels_xy), -1)
    row[idx[usable]] = np.arange(int(usable.sum()))
    values = values[usable] * radiance_per_unit
    keep = (row[pairs.shaded] >= 0) & (row[pairs.lit] >= 0)
    if keep.sum() < MIN_PAIRS:
        return None
    shaded, lit = pairs.shaded[keep], pairs.lit[keep]
    sun_share, bounce_sun, _ = est.in_sun(sun_dir)
    # The pairs ask whether there is a sun at all: their small sky differences are modelled
    # by the overcast sky brighter toward the sun (a pair's shaded patch is shaded exactly
    # toward the sun). Under a clear sky the sun's contrast dwarfs them.
    s, b_model = est.sky_term(PAIR_SKY_TYPE, sun_dir)
    albedo = p.albedo * est._scales.of(p.surface)[:, None] / math.pi
    sky = albedo * (s[:, None] + b_model) * np.asarray(light.sky_horizontal_irradiance, float)
    sun_dir = np.asarray(sun_dir, float) / np.linalg.norm(sun_dir)
    cos_i = np.clip(p.normals @ sun_dir, 0.0, None) * sun_share
    sun = albedo * (cos_i[:, None] + bounce_sun)
    e_sun = pair_sun(values[row[shaded]], values[row[lit]], sky[shaded], sky[lit],
                     sun[shaded], sun[lit])
    return e_sun / max(float(np.mean(light.sky_horizontal_irradiance)), 1e-9)

"""Per-surface albedo scales (server.surfacescale): known answers from planted linear models.

Samples are drawn as ``y = s_p * (A x)`` with a known light ``x`` and known scales ``s_p``
(written here, not by the code under test), with noise and outliers; the learned scales must
find the one wrong surface, leave right ones alone, and follow the evidence across frames.
"""

from __future__ import annotations

import numpy as np
import pytest

from server.surfacescale import ALBEDO_TRUST, SurfaceScales, surfaces_by_albedo

LIGHT = np.array([800.0, 80.0])  # sun normal irradiance, sky irradiance (arbitrary units)


def _frame(rng, true_scale, sizes, lit_fraction, outliers=0.1):
    """One frame of samples: (surface (n,), A (n, 2), y (n,)). ``lit_fraction[p]`` of surface
    p's samples see the sun (cosine 0.3-1), the rest only the sky (terms 0.3-1)."""
    surface, rows = [], []
    for p, (n, lit) in enumerate(zip(sizes, lit_fraction, strict=True)):
        in_sun = rng.random(n) < lit
        a = np.where(in_sun, rng.uniform(0.3, 1.0, n), 0.0)
        c = rng.uniform(0.3, 1.0, n)
        surface.append(np.full(n, p))
        rows.append(np.column_stack([a, c]))
    surface, A = np.concatenate(surface), np.vstack(rows)
    y = np.asarray(true_scale)[surface] * (A @ LIGHT) * (1.0 + rng.normal(0.0, 0.01, len(A)))
    bad = rng.random(len(y)) < outliers  # people, wet patches
    y[bad] *= rng.choice([0.3, 0.5, 2.0], int(bad.sum()))
    return surface, A, y


def _learn(true_scale, frames=4, seed=0, sizes=(300, 120, 40), lit=(0.6, 0.0, 0.5)):
    rng = np.random.default_rng(seed)
    pool = np.repeat(np.arange(3), [2600, 300, 100])  # the ground fills most of the view
    scales = SurfaceScales(pool)
    for _ in range(frames):
        surface, A, y = _frame(rng, true_scale, sizes, lit)
        scales.refit(surface, A, y)
        scales.end_frame()
    return scales


@pytest.mark.parametrize("wrong", [0.7, 1.3])
def test_a_shaded_surface_with_a_wrong_albedo_is_found(wrong):
    # surface 1 is seen only in shade (a building's north face) and is `wrong` x its albedo
    scales = _learn([1.0, 1.0 / wrong, 1.0])
    assert scales.scale[1] == pytest.approx(1.0 / wrong, rel=0.03)
    assert scales.scale[0] == pytest.approx(1.0, abs=1e-9)  # the level: the view's median
    assert scales.scale[2] == pytest.approx(1.0, rel=0.03)
    used = scales.of(np.array([0, 1, 2]))
    assert used[1] == pytest.approx(1.0 / wrong, rel=0.03) and used[0] == 1.0


def test_right_albedos_are_left_alone():
    scales = _learn([1.0, 1.0, 1.0])
    assert np.allclose(scales.scale, 1.0, rtol=0.03)
    assert np.all(scales.of(np.arange(3)) == 1.0)


def test_a_small_error_within_the_trust_is_not_acted_on():
    small = 1.0 + 0.5 * ALBEDO_TRUST
    scales = _learn([1.0, small, 1.0])
    assert scales.scale[1] == pytest.approx(small, rel=0.03)  # learned ...
    assert scales.of(np.array([1]))[0] == 1.0  # ... but the stated albedo is kept


def test_one_surface_alone_has_no_scale_to_learn():
    rng = np.random.default_rng(1)
    scales = SurfaceScales(np.zeros(100, int))
    surface, A, y = _frame(rng, [0.6], (300,), (0.5,))
    scales.refit(surface, A, y)
    scales.end_frame()
    assert scales.scale[0] == 1.0 and scales.evidence[0] == 0.0


def test_surfaces_are_the_faces_of_one_stated_albedo():
    albedo = np.array([[0.2, 0.2, 0.2], [0.5, 0.4, 0.3], [0.2, 0.2, 0.2], [0.5, 0.4, 0.3]])
    s = surfaces_by_albedo(albedo)
    assert s[0] == s[2] and s[1] == s[3] and s[0] != s[1]


def test_a_surface_seen_in_too_few_samples_keeps_its_albedo():
    # surface 2 has fewer samples than a scale needs: it keeps its stated albedo (1) while
    # the others' scales are solved and levelled (a wall sliver in the kiosk's view)
    scales = _learn([1.0, 1.0 / 0.7, 1.0], sizes=(300, 120, 5))
    assert scales.scale[2] == 1.0 and not scales.rescaled[2]
    assert scales.scale[1] == pytest.approx(1.0 / 0.7, rel=0.03)

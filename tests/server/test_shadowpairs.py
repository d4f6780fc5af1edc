"""Shadow-edge pairs (server.shadowpairs): which samples pair up, and the sun they read.

Known answers: pools laid out by hand, and radiances made from a known sun and sky with the
pairs' own Lambertian relation (the arithmetic, not the estimator's model, is under test).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.shadowpairs import pair_sun, shadow_pairs

SUN = np.array([0.0, 0.6, -0.8])  # unit: up and to the north


def _pool(rows):
    """Arrays of a pool from rows (x_px, y_px, point, normal, surface, sky_view, sun_share)."""
    cols = list(zip(*rows, strict=True))
    return dict(pixels_xy=np.array(cols[0:2], float).T, points_m=np.array(cols[2], float),
                normals=np.array(cols[3], float), surface=np.array(cols[4]),
                sky_view=np.array(cols[5], float), sun_share=np.array(cols[6], float))


UP = (0.0, 1.0, 0.0)
SOUTH_FACE = (0.0, 0.0, 1.0)  # faces +Z, away from the sun (its own shadow, not a cast one)


def test_a_shaded_patch_pairs_with_the_nearest_sunlit_ones_of_its_plane_only():
    pool = _pool([
        (10, 10, (0, 0, 0), UP, 0, 0.80, 0.0),    # 0 shaded ground
        (13, 10, (1, 0, 0), UP, 0, 0.85, 1.0),    # 1 lit ground, 3 px: pair
        (10, 16, (0, 0, 2), UP, 0, 0.88, 1.0),    # 2 lit ground, 6 px: pair (second)
        (30, 10, (9, 0, 0), UP, 0, 0.90, 1.0),    # 3 lit ground, 20 px: too far
        (11, 11, (0, 1, 0), UP, 0, 0.85, 1.0),    # 4 lit, same normal, other plane (1 m up)
        (12, 10, (0.5, 0, 0), UP, 1, 0.85, 1.0),  # 5 lit, another surface (albedo)
        (10, 12, (0, 0, 0.5), UP, 0, 0.50, 1.0),  # 6 lit, sky view 0.3 apart
        (12, 12, (0.5, 0, 0.5), UP, 0, 0.80, 0.5),  # 7 a shadow edge crosses it
        (40, 40, (5, 2, 5), SOUTH_FACE, 2, 0.5, 0.0),  # 8 turned from the sun: not a cast one
        (42, 40, (6, 2, 5), SOUTH_FACE, 2, 0.5, 1.0),  # 9 (would be lit: never paired)
    ])
    pairs = shadow_pairs(**pool, sun_dir=SUN)
    assert pairs.shaded.tolist() == [0, 0]
    assert pairs.lit.tolist() == [1, 2]  # nearest first


def test_at_most_per_shaded_pairs_and_none_without_shadow():
    rows = [(10, 10, (0, 0, 0), UP, 0, 0.8, 0.0)] + [
        (10 + d, 10, (0.1 * d, 0, 0), UP, 0, 0.8, 1.0) for d in range(1, 8)]
    pairs = shadow_pairs(**_pool(rows), sun_dir=SUN, per_shaded=3)
    assert pairs.lit.tolist() == [1, 2, 3]
    lit_only = _pool([(10 + d, 10, (0.1 * d, 0, 0), UP, 0, 0.8, 1.0) for d in range(4)])
    assert len(shadow_pairs(**lit_only, sun_dir=SUN)) == 0


@pytest.mark.parametrize("e_sun", [0.0, 40.0, 750.0])
def test_pair_sun_reads_the_sun_that_made_the_radiances(e_sun):
    """L = rho / pi * (E_sun * cos_i * in_sun + k * S) for both patches of each pair, with S
    and the albedo differing between pairs: the pairs read E_sun exactly."""
    rng = np.random.default_rng(3)
    n = 25
    rho = rng.uniform(0.1, 0.6, (n, 3))
    k = np.array([110.0, 120.0, 140.0])  # the sky's horizontal irradiance, RGB
    s_lit = rng.uniform(0.6, 1.0, n)
    s_shaded = s_lit - rng.uniform(0.0, 0.1, n)
    cos_i = rng.uniform(0.3, 0.9, n)
    sky_lit = rho / math.pi * k * s_lit[:, None]
    sky_shaded = rho / math.pi * k * s_shaded[:, None]
    sun_lit = rho / math.pi * cos_i[:, None]
    sun_shaded = np.zeros_like(sun_lit)
    radiance_lit = sky_lit + e_sun * sun_lit
    radiance_shaded = sky_shaded
    assert pair_sun(radiance_shaded, radiance_lit, sky_shaded, sky_lit, sun_shaded,
                    sun_lit) == pytest.approx(e_sun, abs=1e-9)


def test_pair_sun_is_the_median_a_person_in_a_few_pairs_does_not_move():
    n = 21
    rho = np.full((n, 3), 0.3)
    sky = rho / math.pi * 100.0
    sun_lit = rho / math.pi * 0.7
    radiance_lit = sky + 500.0 * sun_lit
    radiance_lit[:4] = 0.02  # a dark coat over four sunlit patches
    got = pair_sun(sky, radiance_lit, sky, sky, np.zeros_like(sky), sun_lit)
    assert got == pytest.approx(500.0, rel=1e-9)

"""The sun's oracle (``bake.sunlight``) against an independent computation and geometry.

The reference here shares no code with the oracle: the sun's disc is sampled on a jittered
polar grid in its tangent plane (not a golden-angle spiral) and the rays are cast through
trimesh's pure-Python triangle intersector (not Embree) against the box mesh this test makes,
not the build's ``site.glb``.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_triangle import RayMeshIntersector

from bake.evaluate import Build
from daylit.sky import SUN_ANGULAR_RADIUS_DEG, direction_from_azimuth_elevation
from tests.conftest import SUN_WALL_SIZE_M
from tests.sites import box

SUN_ELEVATION_DEG = 30.0
SUN_AZIMUTH_DEG = 180.0  # from the south: the wall's shadow falls north (toward -Z)
E_SUN_W_M2 = 800.0


def reference_visible_fraction(mesh, points, normal, sun, rings=32, sectors=32, seed=3):
    """Fraction of the disc seen from each point: ``rings * sectors`` jittered samples, equal
    area each, in the disc's tangent plane; rays through trimesh's triangle intersector."""
    rng = np.random.default_rng(seed)
    u = (np.arange(rings)[:, None] + rng.random((rings, sectors))) / rings
    v = (np.arange(sectors)[None, :] + rng.random((rings, sectors))) / sectors
    radius = np.tan(np.radians(SUN_ANGULAR_RADIUS_DEG)) * np.sqrt(u.ravel())
    phi = 2.0 * np.pi * v.ravel()
    east = np.cross([0.0, 1.0, 0.0], sun)
    east /= np.linalg.norm(east)
    up = np.cross(sun, east)
    dirs = sun + (radius * np.cos(phi))[:, None] * east + (radius * np.sin(phi))[:, None] * up
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rays = RayMeshIntersector(mesh)
    origins = np.repeat(points + 1e-3 * np.asarray(normal), len(dirs), axis=0)
    blocked = rays.intersects_any(origins, np.tile(dirs, (len(points), 1)))
    return 1.0 - blocked.reshape(len(points), len(dirs)).mean(axis=1)


def crossing_m(z_m, visible, level):
    """Where a profile rising from 0 (umbra) to 1 (full sun) first reaches ``level``."""
    i = int(np.argmax(visible >= level))
    assert i > 0, "the profile must start in the umbra"
    t = (level - visible[i - 1]) / (visible[i] - visible[i - 1])
    return z_m[i - 1] + t * (z_m[i] - z_m[i - 1])


def segment_fraction(t):
    """Fraction of a uniform disc beyond a straight edge at ``t`` radii from its centre."""
    return (np.arccos(t) - t * np.sqrt(1.0 - t * t)) / np.pi


@pytest.fixture(scope="module")
def build(sun_site_build):
    return Build(sun_site_build)


def test_penumbra_behind_a_wall_matches_an_independent_ray_cast(build):
    width_m, height_m, depth_m = SUN_WALL_SIZE_M
    sun = direction_from_azimuth_elevation(SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)
    el = np.radians(SUN_ELEVATION_DEG)
    # Geometry: the top edge (5 m high, at z = -0.5) shadows the ground 10 m away along the ray.
    distance_m = height_m / np.sin(el)
    edge_z_m = -depth_m / 2 - height_m / np.tan(el)
    full_width_m = 2.0 * distance_m * np.tan(np.radians(SUN_ANGULAR_RADIUS_DEG)) / np.sin(el)
    t = np.linspace(-1.0, 1.0, 200001)
    t90 = t[np.argmin(np.abs(segment_fraction(t) - 0.9))]
    geometric_10_90_m = -t90 * full_width_m  # symmetric: from -t90 to +t90 radii
    assert distance_m == pytest.approx(10.0)

    # A line across the edge (x = 0, far from the wall's ends), from the umbra outward.
    z_m = np.arange(edge_z_m + 0.24, edge_z_m - 0.24, -0.004)
    points = np.stack([np.zeros_like(z_m), np.zeros_like(z_m), z_m], axis=1)
    up = np.array([0.0, 1.0, 0.0])
    oracle = build.sun_irradiance(points, up, sun, E_SUN_W_M2)
    mesh = box(list(SUN_WALL_SIZE_M), [0.0, 0.0, 0.0])
    reference = reference_visible_fraction(mesh, points, up, sun)
    v = oracle["visible_with"]

    widths = [crossing_m(z_m, p, 0.9) - crossing_m(z_m, p, 0.1) for p in (v, reference)]
    edges = [crossing_m(z_m, p, 0.5) for p in (v, reference)]
    # Distances run toward -z: widths come out negative; compare magnitudes.
    width_oracle_m, width_reference_m = -widths[0], -widths[1]
    print(
        f"\n10-90 width: oracle {width_oracle_m * 100:.2f} cm, reference "
        f"{width_reference_m * 100:.2f} cm, geometric {geometric_10_90_m * 100:.2f} cm; "
        f"50 % point: oracle {edges[0]:.4f} m, reference {edges[1]:.4f} m, geometric "
        f"{edge_z_m:.4f} m; max |V - V_ref| {np.abs(v - reference).max():.3f}"
    )
    assert width_oracle_m == pytest.approx(width_reference_m, rel=0.2)
    assert width_reference_m == pytest.approx(geometric_10_90_m, rel=0.1)
    assert width_oracle_m == pytest.approx(geometric_10_90_m, rel=0.2)
    assert abs(edges[0] - edges[1]) < 0.02
    assert abs(edges[0] - edge_z_m) < 0.02

    direct_full_w_m2 = E_SUN_W_M2 * np.sin(el)
    lit, umbra = reference == 1.0, reference == 0.0
    assert lit.sum() > 10 and umbra.sum() > 10
    assert np.allclose(oracle["with"][lit], direct_full_w_m2, rtol=0.02)
    assert np.all(oracle["with"][umbra] < 0.01 * direct_full_w_m2)
    assert np.allclose(oracle["cos"], np.sin(el))


def test_real_shadows_are_in_both_terms_virtual_ones_only_with(build):
    sun = direction_from_azimuth_elevation(SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)
    behind_shed, behind_wall, open_ground = [12.0, 0.0, -5.0], [0.0, 0.0, -5.0], [-20, 0, 15]
    points = np.array([behind_shed, behind_wall, open_ground], dtype=float)
    result = build.sun_irradiance(points, [0, 1, 0], sun, [800.0, 700.0, 600.0])
    assert result["visible_with"].tolist() == [0.0, 0.0, 1.0]
    assert result["visible_without"].tolist() == [0.0, 1.0, 1.0]
    cos = np.sin(np.radians(SUN_ELEVATION_DEG))
    assert np.allclose(result["without"][1], np.array([800.0, 700.0, 600.0]) * cos)
    assert np.allclose(result["with"][1], 0.0)
    casters = build.sun_casters
    assert casters.visible_fraction(points, [0, 1, 0], sun, "virtual").tolist() == [1, 0, 1]
    assert casters.visible_fraction(points, [0, 1, 0], sun, "real").tolist() == [0, 1, 1]
    assert casters.visible_fraction(points, [0, 1, 0], sun, "none").tolist() == [1, 1, 1]
    # Only the virtual and real meshes cast: the ground (y = 0) never hides the sun above it.
    assert casters.face_counts["virtual"] > 0 and casters.face_counts["real"] > 0


def test_surfaces_facing_away_and_the_horizon(build):
    casters = build.sun_casters
    north_face = [[0.0, 2.0, -0.5]]  # the wall's own shaded side
    sun = direction_from_azimuth_elevation(SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)
    assert casters.visible_fraction(north_face, [0, 0, -1], sun).tolist() == [0.0]
    # The sun's centre on the horizon: its lower half is hidden by the open ground.
    facing_east = casters.visible_fraction([[-20.0, 1.0, 15.0]], [1, 0, 0], [1.0, 0.0, 0.0])
    assert facing_east[0] == pytest.approx(0.5, abs=0.03)


def test_bad_arguments_are_refused(build):
    with pytest.raises(ValueError, match="casters must be one of"):
        build.sun_casters.visible_fraction([[0, 0, 0]], [0, 1, 0], [0, 1, 0], "ground")
    with pytest.raises(ValueError, match="normal is zero"):
        build.sun_casters.visible_fraction([[0, 0, 0]], [0, 0, 0], [0, 1, 0])


def test_reference_sees_what_it_should():
    # The reference's own sanity: a roof over the point hides the sun, beside it does not.
    roof = trimesh.creation.box(extents=[10.0, 0.1, 10.0])
    roof.apply_translation([0.0, 5.0, 0.0])
    sun = direction_from_azimuth_elevation(180.0, 60.0)
    points = np.array([[0.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    assert reference_visible_fraction(roof, points, [0, 1, 0], sun).tolist() == [0.0, 1.0]

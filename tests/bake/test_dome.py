"""The light dome tiles the upper hemisphere exactly (Sato 2.1, Kakuta 2.2.1)."""

import numpy as np
import pytest

from bake.dome import Dome
from daylit.spherical import (
    PatchLookup,
    clipped_cosine_integral,
    contains,
    normalize,
    sample_triangles,
    solid_angle,
)

DOMES = [
    ("icosahedral", 2),
    ("icosahedral", 4),
    ("icosahedral", 6),
    ("octahedral", 3),
    ("octahedral", 10),
    ("icosahedral", 10),
]


@pytest.mark.parametrize(("kind", "frequency"), DOMES)
def test_solid_angles_sum_to_two_pi(kind, frequency):
    dome = Dome.build(kind, frequency)
    total = dome.solid_angles_sr.sum()
    assert abs(total / (2 * np.pi) - 1.0) < 1e-9
    assert np.all(dome.solid_angles_sr > 0)


@pytest.mark.parametrize(("kind", "frequency"), DOMES)
def test_every_direction_above_the_horizon_lies_in_exactly_one_patch(kind, frequency):
    dome = Dome.build(kind, frequency)
    rng = np.random.default_rng(7)
    dirs = normalize(rng.normal(size=(20000, 3)))
    dirs[:, 1] = np.abs(dirs[:, 1]) + 1e-9
    dirs = normalize(dirs)
    counts = contains(dome.vertices, dirs).sum(axis=1)
    assert np.all(counts == 1)
    below = dirs * np.array([1, -1, 1])
    assert not contains(dome.vertices, below).any()


@pytest.mark.parametrize(("kind", "frequency"), DOMES)
def test_patch_lookup_agrees_with_exhaustive_containment(kind, frequency):
    dome = Dome.build(kind, frequency)
    rng = np.random.default_rng(3)
    dirs = normalize(rng.normal(size=(5000, 3)))
    dirs[:, 1] = np.abs(dirs[:, 1])
    # Also directions exactly on vertices and edges, where ties must still give one patch.
    on_edges = normalize(dome.vertices[:, 0] + dome.vertices[:, 1])
    dirs = np.concatenate([dirs, dome.vertices[:, 0], on_edges])
    index = PatchLookup(dome.vertices)(dirs)
    assert np.all(index >= 0)
    assert np.all(contains(dome.vertices, dirs, tolerance=1e-9)[np.arange(len(dirs)), index])
    assert np.all(PatchLookup(dome.vertices)(-np.abs(dirs[:10]) - [0, 1e-3, 0]) == -1)


@pytest.mark.parametrize(
    ("requested", "count", "kind"),
    [
        (40, 40, "icosahedral"),
        (160, 160, "icosahedral"),
        (400, 400, "octahedral"),
        (360, 360, "icosahedral"),
        (1000, 1000, "icosahedral"),
        (45, 40, "icosahedral"),
    ],
)
def test_light_count_is_matched(requested, count, kind):
    dome = Dome.for_light_count(requested)
    assert dome.count == count
    assert dome.kind == kind


def test_kakuta_dome_is_forty_lights():
    assert Dome.build("icosahedral", 2).count == 40


def test_lambert_polygon_irradiance_is_exact_for_a_uniform_sky():
    # Upward: pi; vertical: pi/2; tilted by t: pi (1 + cos t) / 2; facing down: 0.
    dome = Dome.for_light_count(160)
    tilt = np.radians(30.0)
    normals = np.array([[0, 1, 0], [1, 0, 0], [0, np.cos(tilt), np.sin(tilt)], [0, -1, 0]])
    E = clipped_cosine_integral(dome.vertices, normals).sum(axis=1)
    expected = np.pi * np.array([1.0, 0.5, (1 + np.cos(tilt)) / 2, 0.0])
    assert np.allclose(E, expected, rtol=1e-12, atol=1e-12)


def test_lambert_matches_quadrature_per_patch():
    """Exact clipped-polygon irradiance against a fine solid-angle-weighted quadrature.

    The quadrature uses ``sample_triangles``, so this also checks its Jacobian weights.
    """
    dome = Dome.for_light_count(40)
    normal = normalize(np.array([[0.3, 0.5, -0.8]]))  # tilted: clips many patches
    exact = clipped_cosine_integral(dome.vertices, normal)[0]
    k = 300
    grid = (np.arange(k) + 0.5) / k
    uv = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 1, 2)
    dirs, weight = sample_triangles(dome.vertices, np.broadcast_to(uv, (k * k, dome.count, 2)))
    cos = np.maximum(dirs @ normal[0], 0.0)
    quadrature = (weight * cos).sum(axis=0) / weight.sum(axis=0) * solid_angle(dome.vertices)
    assert np.allclose(quadrature, exact, atol=2e-6)


def test_manifest_lists_every_light_in_index_order():
    dome = Dome.for_light_count(160)
    m = dome.to_manifest()
    assert m["count"] == 160
    for i, light in enumerate(m["lights"]):
        assert light["index"] == i
        v = np.array(light["vertices"])
        assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
        assert np.isclose(light["solid_angle_sr"], solid_angle(v[None])[0])

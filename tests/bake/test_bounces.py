"""More than one bounce (``[quality] bounces``): known answers.

- **Closed diffuse box.** Inside a closed box of albedo ``rho`` every gather ray hits an inner
  face. With the direct irradiance ``E`` the same at every cache point, the light a receiver
  inside gathers after N bounces is ``E (rho + rho^2 + ... + rho^N)``: the geometric series,
  through the bake's own gather (rays, cache look-up, sparse products).
- **L-shaped courtyard at albedo 0.6** (test_contact.py holds the baked comparison against an
  independent path tracer through trimesh's ray queries, tests/bake/paths.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from bake.cachepoints import cache_points
from bake.dome import Dome
from bake.irradiance import (
    BounceCache,
    Estimator,
    SceneSet,
    cache_bounces,
    write_shared_cache,
)
from bake.raytrace import Geometry
from bake.scene import SceneError, load_site
from tests.sites import make_site


def _inside_of_a_box(rho: float) -> Geometry:
    """A closed 4 x 3 x 5 m box, 1 m above the ground plane, its faces turned inward."""
    mesh = trimesh.creation.box(extents=[4.0, 3.0, 5.0])
    mesh.apply_translation([0.0, 2.5, 0.0])
    mesh.invert()
    n = len(mesh.faces)
    return Geometry(
        np.asarray(mesh.vertices), np.asarray(mesh.faces), np.full((n, 3), rho),
        np.zeros(n, bool), np.zeros(n, int),
    )


@pytest.mark.parametrize("bounces", [1, 2, 3, 6])
def test_inside_a_closed_box_the_bounces_sum_the_geometric_series(bounces):
    rho, E0 = 0.6, 2.5
    geometry = _inside_of_a_box(rho)
    rng = np.random.default_rng(5)
    points, normals, faces = cache_points(geometry, 0.5, 1.5, rng)
    assert np.all(np.bincount(faces, minlength=len(geometry.faces)) > 0)
    dome = Dome.for_light_count(40)
    n = dome.count
    E = {"all": np.full((len(points), n), E0, np.float32)}
    cache = BounceCache(points, normals, faces, geometry.albedo[faces], E, geometry, 0.25)
    scenes = SceneSet.build(geometry, np.zeros(3))
    estimator = Estimator(dome.vertices, scenes, 2, 32, cache)
    own = cache_bounces(estimator, bounces, np.random.default_rng(1))
    if bounces == 1:
        assert own is None
    else:
        expected_own = E0 * sum(rho**k for k in range(1, bounces))
        assert np.allclose(own["all"], expected_own, rtol=1e-5)
    cache = BounceCache(points, normals, faces, geometry.albedo[faces], E, geometry, 0.25, own)
    estimator = Estimator(dome.vertices, scenes, 2, 32, cache)
    # Receivers on the floor and a wall, inside.
    receivers = np.array([[0.3, 1.0, -0.7], [2.0, 2.0, 1.1]])
    receiver_normals = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    gathered = estimator.bounce(receivers, receiver_normals, "all", np.random.default_rng(2))
    expected = E0 * sum(rho**k for k in range(1, bounces + 1))
    assert gathered.shape == (2, n, 3)
    assert np.allclose(gathered, expected, rtol=1e-5)


def test_bounces_is_read_and_checked(tmp_path):
    site = load_site(make_site(tmp_path / "a", bounces=4))
    assert site.settings.bounces == 4
    text = (tmp_path / "a" / "scene.toml").read_text()
    for bad, words in (("0", "bounces"), ("2.5", "bounces"), ('"two"', "bounces")):
        (tmp_path / "a" / "scene.toml").write_text(text.replace("bounces = 4", f"bounces = {bad}"))
        with pytest.raises(SceneError, match=words):
            load_site(tmp_path / "a")
    (tmp_path / "a" / "scene.toml").write_text(text.replace("bounces = 4\n", ""))
    from bake.scene_schema import DEFAULT_BOUNCES

    assert load_site(tmp_path / "a").settings.bounces == DEFAULT_BOUNCES


def test_the_workers_gather_from_the_mapped_cache_as_from_the_cache_itself(tmp_path):
    """The local pool's workers read what a gather ray picks up from files memory-mapped by
    them all (write_shared_cache, BounceCache.from_files): inside the closed box, three
    bounces, the gathered light is the geometric series through them too, and the same bits
    as through the cache built from the arrays themselves (a cluster's workers, and before)."""
    rho, E0, bounces = 0.6, 2.5, 3
    geometry = _inside_of_a_box(rho)
    points, normals, faces = cache_points(geometry, 0.5, 1.5, np.random.default_rng(5))
    dome = Dome.for_light_count(40)
    n = dome.count
    E = {config: np.full((len(points), n), E0, np.float32) for config in ("all", "real")}
    cache = BounceCache(points, normals, faces, geometry.albedo[faces], E, geometry, 0.25)
    scenes = SceneSet.build(geometry, np.zeros(3))
    own = cache_bounces(Estimator(dome.vertices, scenes, 2, 32, cache), bounces,
                        np.random.default_rng(1))
    arrays = dict(points=points, normals=normals, faces=faces, albedo=geometry.albedo[faces],
                  E_all=E["all"], E_real=E["real"], cell_m=0.25, B_all=own["all"],
                  B_real=own["real"])
    cache_file = tmp_path / "cache.npz"
    write_shared_cache(cache_file, E, arrays["albedo"], own, rows=7)  # several blocks
    np.savez(cache_file, **arrays)
    mapped = BounceCache.from_files(cache_file, geometry)
    assert isinstance(mapped.picked_up("all"), np.memmap)  # mapped, not loaded
    assert not mapped.E  # the irradiance itself is not held
    with np.load(cache_file) as data:
        held = BounceCache.from_arrays(data, geometry)
    receivers = np.array([[0.3, 1.0, -0.7], [2.0, 2.0, 1.1]])
    receiver_normals = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    gathered = {
        name: Estimator(dome.vertices, scenes, 2, 32, c).bounce(
            receivers, receiver_normals, "all", np.random.default_rng(2))
        for name, c in (("mapped", mapped), ("held", held))
    }
    assert np.array_equal(gathered["mapped"], gathered["held"])
    expected = E0 * sum(rho**k for k in range(1, bounces + 1))
    assert np.allclose(gathered["mapped"], expected, rtol=1e-5)
    # A cache written before the shared files existed is read as before.
    for path in tmp_path.glob("cache-*.npy"):
        path.unlink()
    assert BounceCache.from_files(cache_file, geometry).picked is None


def test_the_cache_bounces_by_blocks_of_lights_are_the_same_bits():
    """cache_bounces works through the lights in blocks (its temporaries bounded): blocks of
    one and of seven lights give the same bits as all the lights at once, under a sky whose
    lights differ (each light's own direct irradiance, varied over the cache points)."""
    geometry = _inside_of_a_box(0.6)
    points, normals, faces = cache_points(geometry, 0.5, 1.5, np.random.default_rng(5))
    dome = Dome.for_light_count(40)
    varied = np.random.default_rng(3).uniform(0.5, 3.0, (len(points), dome.count))
    E = {"all": varied.astype(np.float32), "real": (0.5 * varied).astype(np.float32)}
    cache = BounceCache(points, normals, faces, geometry.albedo[faces], E, geometry, 0.25)
    estimator = Estimator(dome.vertices, SceneSet.build(geometry, np.full(3, 0.2)), 2, 32, cache)
    row_bytes = len(points) * 3 * 8
    whole, ones, sevens = (
        cache_bounces(estimator, 3, np.random.default_rng(1), light_block_bytes=size)
        for size in (1 << 40, row_bytes, 7 * row_bytes)
    )
    for config in E:
        assert whole[config].dtype == np.float32 and whole[config].shape == (len(points),
                                                                             dome.count, 3)
        assert np.array_equal(whole[config], ones[config])
        assert np.array_equal(whole[config], sevens[config])
        assert whole[config].std(axis=1).mean() > 0  # the lights differ

"""Parts of the tracing: chunk files, the direct light's sample rays, the look-up of a bounce
hit's cache point."""

from __future__ import annotations

import numpy as np
import pytest

from bake import chunkio
from bake.dome import Dome
from bake.irradiance import BounceCache, Estimator, SceneSet
from bake.raytrace import Geometry
from tests.sites import box


def test_chunks_read_back_exactly_and_in_order(tmp_path):
    rng = np.random.default_rng(3)
    chunks = [
        {"all": rng.random((rows, 5)).astype(np.float32),
         "bounce:all": rng.random((rows, 5, 3)).astype(np.float32)}
        for rows in (4, 7, 1)
    ]
    paths = []
    for index, arrays in enumerate(chunks):
        paths.append(tmp_path / f"c{index}{chunkio.SUFFIX}")
        chunkio.save_chunk(paths[-1], arrays)
    assert not list(tmp_path.glob("*.tmp"))
    loaded = chunkio.load_chunks(paths)
    assert sorted(loaded) == ["all", "bounce:all"]
    for name in loaded:
        expected = np.concatenate([c[name] for c in chunks])
        assert loaded[name].dtype == expected.dtype
        assert np.array_equal(loaded[name], expected)
    # The order of the paths is the order of the rows.
    reversed_rows = chunkio.load_chunks(paths[::-1])["all"]
    assert np.array_equal(reversed_rows, np.concatenate([c["all"] for c in chunks[::-1]]))


def test_a_truncated_or_mismatched_chunk_is_an_error(tmp_path):
    a, b = tmp_path / f"a{chunkio.SUFFIX}", tmp_path / f"b{chunkio.SUFFIX}"
    chunkio.save_chunk(a, {"all": np.ones((3, 4), np.float32)})
    chunkio.save_chunk(b, {"all": np.ones((3, 5), np.float32)})
    with pytest.raises(ValueError, match="does not match"):
        chunkio.load_chunks([a, b])
    chunkio.save_chunk(b, {"all": np.ones((3, 4), np.float32), "real": np.ones((3, 4))})
    with pytest.raises(ValueError, match="holds"):
        chunkio.load_chunks([a, b])
    a.write_bytes(a.read_bytes()[:-8])
    with pytest.raises(ValueError, match="truncated"):
        chunkio.load_chunks([a])


def _box_geometry(size, base_center, virtual=True):
    mesh = box(size, base_center)
    n = len(mesh.faces)
    return Geometry(
        np.asarray(mesh.vertices), np.asarray(mesh.faces), np.full((n, 3), 0.5),
        np.full(n, virtual), np.zeros(n, int),
    )


def _cache_on(geometry, points, faces, cell_m):
    n = len(points)
    E = {"all": np.ones((n, 2), np.float32)}
    return BounceCache(
        points, geometry.face_normals[faces], faces, np.full((n, 3), 0.5), E, geometry, cell_m
    )


def test_a_bounce_hit_reads_the_nearest_cache_point_of_its_own_face():
    """Against a brute-force search: the chosen point is on the hit's face and no more than
    a raster cell's diagonal farther than the nearest one; a face without cache points
    gives -1."""
    geometry = _box_geometry([4.0, 2.0, 3.0], [0.0, 1.0, 0.0])
    rng = np.random.default_rng(7)
    tri = geometry.vertices[geometry.faces]

    def on_faces(faces):
        a, b = rng.random((2, len(faces)))
        flip = a + b > 1.0
        a[flip], b[flip] = 1.0 - a[flip], 1.0 - b[flip]
        t = tri[faces]
        return t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])

    cache_faces = np.repeat(np.arange(11), 30)  # face 11 gets no cache point
    cache_points = on_faces(cache_faces)
    cell_m = 0.05
    cache = _cache_on(geometry, cache_points, cache_faces, cell_m)

    hit_faces = rng.integers(0, 12, 4000)
    hits = on_faces(hit_faces)
    index = cache.nearest(hits, hit_faces)
    assert np.all(index[hit_faces == 11] == -1)
    ok = hit_faces != 11
    assert np.all(cache_faces[index[ok]] == hit_faces[ok])
    chosen = np.linalg.norm(cache_points[index[ok]] - hits[ok], axis=1)
    same_face = cache_faces[None, :] == hit_faces[ok][:, None]
    distances = np.linalg.norm(hits[ok][:, None, :] - cache_points[None, :, :], axis=2)
    best = np.where(same_face, distances, np.inf).min(axis=1)
    assert np.all(chosen <= best + np.sqrt(2.0) * cell_m + 1e-9)
    assert np.mean(np.isclose(chosen, best)) > 0.8  # mostly the very nearest


def test_direct_light_of_points_facing_up_and_down_under_an_open_sky():
    """Far from the only object, a point facing up gets each patch's exact unoccluded
    irradiance (pi in all at unit radiance), one facing down none; a chunk with no point
    that can see any patch traces nothing and is all zeros."""
    dome = Dome.for_light_count(40)
    scenes = SceneSet.build(_box_geometry([1.0, 1.0, 1.0], [50.0, 0.0, 0.0]), np.zeros(3))
    estimator = Estimator(dome.vertices, scenes, samples_per_patch=4, bounce_rays=0)
    points = np.array([[0.0, 1.0, 0.0], [0.0, 2.0, 0.0]])
    up_down = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    E = estimator.direct(points, up_down, ("all", "real"), np.random.default_rng(1))
    for config in ("all", "real"):
        assert E[config].shape == (2, dome.count)
        assert E[config][0].sum() == pytest.approx(np.pi, rel=1e-6)
        assert np.array_equal(E[config][1], np.zeros(dome.count))
    estimator.rays_cast = 0
    down_only = estimator.direct(points, -np.abs(up_down), ("all",), np.random.default_rng(1))
    assert estimator.rays_cast == 0 and not down_only["all"].any()


def test_a_wall_hides_the_patches_behind_it_and_part_of_those_on_its_edge():
    """A long wall to the east whose top is 45 degrees up from the point: patches wholly to
    the west keep their exact value, patches wholly east and below 45 degrees get none,
    patches across its top edge get a part (soft shadows from sampling the patch)."""
    dome = Dome.for_light_count(160)
    wall = _box_geometry([0.2, 2.0, 200.0], [1.0, -1.0, 0.0])  # x 0.9..1.1, y -1..1
    scenes = SceneSet.build(wall, np.zeros(3))
    estimator = Estimator(dome.vertices, scenes, samples_per_patch=16, bounce_rays=0)
    point, up = np.array([[0.0, 0.1, 0.0]]), np.array([[0.0, 1.0, 0.0]])
    E = estimator.direct(point, up, ("all",), np.random.default_rng(2))["all"][0]
    exact = estimator.exact_unoccluded(up)[0]
    x, y = dome.vertices[:, :, 0], dome.vertices[:, :, 1]  # (n, 3): each patch's corners
    # From the point the wall's top (0.9 up, 0.9 away) is at y = x: below that it is hidden.
    west = np.all(x <= 0.0, axis=1)
    hidden = np.all((x > 0.05) & (y < x - 1e-3), axis=1)
    across_top = np.any(y > x + 0.05, axis=1) & np.any((x > 0.05) & (y < x - 0.05), axis=1)
    assert west.sum() > 10 and hidden.sum() > 10 and across_top.sum() > 3
    assert np.allclose(E[west], exact[west], rtol=1e-6)
    assert np.all(E[hidden] == 0.0)
    fraction = E[across_top] / exact[across_top]
    assert np.all((fraction > 0.0) & (fraction < 1.0))

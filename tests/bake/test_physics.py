"""The baker against physics: known answers, not snapshots of its own output.

All irradiances are read through the evaluation API (``bake.evaluate.Build``), i.e. from the
EXR masters of a real bake, interpolated at the probed point.
"""

from __future__ import annotations

import numpy as np
import pytest

from bake.evaluate import Build
from bake.pipeline import bake
from tests.bake.reference import ReferenceRenderer
from tests.sites import box, make_site, real_box, sphere

QUIET = {"progress": False, "log": lambda msg: None}


@pytest.fixture(scope="module")
def sphere_build(tmp_path_factory):
    """A black sphere (R = 1 m) centred 3 m above a black ground."""
    root = tmp_path_factory.mktemp("sphere")
    scene = make_site(
        root / "scene",
        virtual=[("ball", sphere(1.0, [0, 3, 0]), (0, 0, 0))],
        ground_albedo=(0, 0, 0),
        lights=160,
        direct_rays=2000,
        ground_texel_m=0.5,
    )
    out = root / "build"
    bake(scene, out, **QUIET)
    return Build(out)


def test_open_horizontal_texel_gets_pi_times_radiance(tmp_path):
    # The hull plane on top of a box faces straight up with nothing above it.
    scene = make_site(tmp_path / "scene", ground_albedo=(0.3, 0.3, 0.3))
    bake(scene, tmp_path / "build", **QUIET)
    build = Build(tmp_path / "build")
    top = max(build.atlases["hull"]["receivers"], key=lambda r: r["origin_m"][1])
    assert top["normal"][1] > 0.999
    centre = np.array(top["origin_m"]) + 0.5 * top["texel_m"] * (
        top["rect"][2] * np.array(top["axis_u"]) + top["rect"][3] * np.array(top["axis_v"])
    )
    for L in (1.0, 3.5):
        result = build.irradiance(centre, [0, 1, 0], f"uniform:{L}")
        assert result["sample"].kind == "hull"
        assert np.allclose(result["with"], np.pi * L, rtol=0.01)
        assert np.allclose(result["without"], np.pi * L, rtol=0.01)


def test_ground_under_a_sphere_gets_the_view_factor(sphere_build):
    # pi L (1 - (R/h)^2) straight under a sphere of radius R centred at height h.
    R, h, L = 1.0, 3.0, 2.0
    result = sphere_build.irradiance([0, 0, 0], [0, 1, 0], f"uniform:{L}")
    assert result["sample"].atlas == "ground"
    assert np.allclose(result["with"], np.pi * L * (1 - (R / h) ** 2), rtol=0.02)
    assert np.allclose(result["without"], np.pi * L, rtol=0.01)


def test_vertical_wall_without_ground_reflection_gets_half(tmp_path):
    # A real wall whose east face can catch the box's shadow; ground albedo 0: E = pi L / 2.
    wall = real_box("wall", (0.4, 3.0, 6.0), (3.0, 0.0, 0.0))
    scene = make_site(tmp_path / "scene", real=wall, ground_albedo=(0, 0, 0))
    bake(scene, tmp_path / "build", **QUIET)
    build = Build(tmp_path / "build")
    kinds = {r["kind"] for r in build.atlases["ground"]["receivers"]}
    assert "wall" in kinds
    # West face (toward the box) at x = 2.8; without virtual objects it sees half the sky.
    result = build.irradiance([2.8, 1.5, 0.0], [-1, 0, 0], "uniform:1")
    assert result["sample"].kind == "wall"
    assert np.allclose(result["without"], np.pi / 2, rtol=0.01)
    assert np.all(result["with"] < result["without"])  # the box shades it
    # The far face sees nothing virtual: with and without agree, pi/2.
    far = build.irradiance([3.2, 1.5, 0.0], [1, 0, 0], "uniform:1")
    assert np.allclose(far["with"], np.pi / 2, rtol=0.01)


@pytest.mark.slow
def test_weighted_sum_of_basis_equals_a_direct_render(tmp_path):
    """Linearity (Sato Eq. 6): sum_i r_i B_i(x) equals an independent brute-force render of
    x under the same piecewise-constant sky, including one coloured bounce.

    Stated tolerance: 2% per channel (measured: within 0.7%; 0.61% and 0.54% at the two
    points with the nearest cache point per bounce hit, 0.61% and 0.12% with four). It covers
    the bake's sampling noise at these settings, the reference's (about 0.5%) and the bounce
    cache's spacing.
    """
    cube = box([2.0, 2.0, 2.0], [0, 0, 0])
    ground_albedo = (0.6, 0.35, 0.15)
    scene = make_site(
        tmp_path / "scene",
        virtual=[("cube", cube, (0.1, 0.45, 0.8))],
        ground_albedo=ground_albedo,
        lights=40,
        direct_rays=1600,
        bounce_rays=256,
        ground_texel_m=0.25,
        hull_texel_m=0.25,
    )
    bake(scene, tmp_path / "build", **QUIET)
    build = Build(tmp_path / "build")
    rng = np.random.default_rng(11)
    n = build.light_count
    centroids = np.array([light["centroid"] for light in build.manifest["dome"]["lights"]])
    r = 1.0 + 0.6 * np.clip(centroids @ [0.3, 0.8, 0.5], 0, 1)[:, None] * [0.9, 1.0, 1.3]
    sun = int(np.argmax(centroids @ [-0.5, 0.6, 0.6]))
    r[sun] *= 25.0  # a bright patch: hard-ish shadows and strong bounce
    ground_mesh = _ground(build.manifest["ground"])
    with_cube = ReferenceRenderer(
        [(ground_mesh, ground_albedo), (cube, (0.1, 0.45, 0.8))],
        build.dome_vertices,
        r,
        ground_albedo,
        rng,
    )
    without = ReferenceRenderer(
        [(ground_mesh, ground_albedo)], build.dome_vertices, r, ground_albedo, rng
    )
    # A ground point beside the cube (shadowed by it, lit blue by its bounce) and a point on
    # the hull plane of the cube's side (lit orange by the ground).
    probes = [([-1.5, 0.0, -1.6], [0, 1, 0]), ([1.03, 0.7, 0.2], [1, 0, 0])]
    for point, normal in probes:
        baked = build.irradiance(point, normal, r)
        expected = with_cube.irradiance(point, normal)
        assert np.allclose(baked["with"], expected, rtol=0.02), (point, baked["with"], expected)
        if baked["sample"].atlas == "ground":
            expected_d = without.irradiance(point, normal)
            assert np.allclose(baked["without"], expected_d, rtol=0.02)
    assert n == 40  # the test's sky was built for Kakuta's 40-light dome


def _ground(ground):
    import trimesh

    cx, cz = ground["center_m"]
    sx, sz = ground["size_m"]
    v = np.array(
        [
            [cx - sx / 2, 0, cz - sz / 2],
            [cx + sx / 2, 0, cz - sz / 2],
            [cx + sx / 2, 0, cz + sz / 2],
            [cx - sx / 2, 0, cz + sz / 2],
        ]
    )
    return trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)

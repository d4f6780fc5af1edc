"""Receivers: which surfaces get texels."""

from __future__ import annotations

import numpy as np

from bake import lightmap
from bake.scene import Part
from tests.sites import box


def _part(name, mesh):
    return Part(name, name, mesh, np.full((len(mesh.faces), 3), 0.5))


def test_lightmap_leaves_out_faces_resting_on_the_ground():
    """A box standing on the ground loses its underside (2 of 12 triangles), a box lifted
    1 m keeps it: a visitor can look up at it. No texel of the standing box faces down."""
    standing = _part("standing", box([2.0, 2.0, 2.0], [0.0, 0.0, 0.0]))
    lifted = _part("lifted", box([2.0, 2.0, 2.0], [5.0, 1.0, 0.0]))
    atlas = lightmap.lightmap_atlas([standing, lifted], texel_m=0.25, max_size=1024)
    faces = {r.name: len(r.faces) for r in atlas.receivers}
    assert faces == {"standing": 10, "lifted": 12}
    down = atlas.normals[:, 1] < -0.99
    assert not np.any(down & (atlas.points[:, 1] < 0.01))
    assert np.any(down & np.isclose(atlas.points[:, 1], 1.0))  # the lifted box's underside
    # Every kept face still has texels: 5 faces of 4 m2 at 16 texels/m2, 6 faces lifted.
    standing_texels = np.count_nonzero(atlas.points[:, 0] < 2.5)
    lifted_texels = np.count_nonzero(atlas.points[:, 0] > 2.5)
    assert standing_texels >= 5 * 4 * 16 and lifted_texels >= 6 * 4 * 16
    assert standing_texels < lifted_texels


def test_a_part_lying_flat_on_the_ground_keeps_its_faces():
    """A part made only of ground-resting faces is not emptied (it would have no model)."""
    slab = _part("slab", box([2.0, 0.0, 2.0], [0.0, 0.0, 0.0]))
    slab.mesh.update_faces(slab.mesh.face_normals[:, 1] < -0.99)
    assert len(slab.mesh.faces) == 2
    atlas = lightmap.lightmap_atlas([slab], texel_m=0.25, max_size=1024)
    assert len(atlas.receivers[0].faces) == 2 and atlas.count > 0


def test_hull_planes_inside_overlapping_parts_are_dropped_as_trimesh_finds_them():
    """bake.receivers.drop_buried against trimesh's point-in-mesh test (``contains``) on
    three overlapping parts: a hall, a plinth standing inside it and a screen beside the
    plinth, also inside the hall. The plinth's and the screen's shadowing planes lie inside
    the hall, which no view can see; the hall's lie outside. A plane between the plinth and
    the screen sends most of its probe rays, inside the hall, into the other's face from the
    front: the rule before (90 % of the first hits back faces) kept such planes, each a
    receiver of black texels. Now a ray counts the faces it crosses
    (bake.contact.solid_depth). The ground is in the scene, as in a bake: the hall's floor
    lies on it."""
    import trimesh

    from bake.raytrace import Geometry, RayScene
    from bake.receivers import drop_buried, hull_receivers, plane_texel_points

    hall = _part("hall", box([10.0, 6.0, 10.0], [0.0, 0.0, 0.0]))
    plinth = _part("plinth", box([1.0, 1.0, 1.0], [0.0, 1.5, 0.0]))
    screen = _part("screen", box([1.0, 3.0, 6.0], [1.5, 0.5, 0.0]))
    parts = [hall, plinth, screen]
    planes = hull_receivers(parts, texel_m=0.25, offset_m=0.03, min_area_m2=0.01)
    ground = _part("ground", trimesh.Trimesh(
        [[-30, 0, -30], [30, 0, -30], [30, 0, 30], [-30, 0, 30]], [[0, 2, 1], [0, 3, 2]]))
    scene = RayScene(Geometry.from_parts(parts + [ground], [True] * len(parts) + [False]))
    kept = {r.name for r in drop_buried(planes, scene)}
    # The answer from trimesh: a plane is inside when its texel centres are in a part.
    inside = set()
    for r in planes:
        _, world = plane_texel_points(r)
        held = np.any([p.mesh.contains(world) for p in parts], axis=0)
        if held.mean() > 0.5:
            inside.add(r.name)
    assert {n.split("/")[1] for n in inside} == {"plinth", "screen"}
    assert kept == {r.name for r in planes} - inside

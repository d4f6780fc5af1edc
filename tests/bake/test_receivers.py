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

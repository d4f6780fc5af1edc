"""Samples wholly in the model's shadow for the current sun: the scene estimate's pool topped up.

The scene estimate (``server.sceneestimate``) tells the sky from the sun by surfaces in shadow.
Its pool is random pixels of the view whose 3 x 3 patch reads one plane
(``server.scenesamples.prepare_samples``); a view whose shade is thin or broken (the demo's
kiosk: a tree's shadow 1-2 px wide on the ground, the shaded side of a canopy of faces a few
pixels across) has no such patch in shadow, and then nothing in the frame separates the sun
from the sky: the fit reads the sky from sunlit ground alone, where the sun and the sky are
nearly collinear (docs/server.md).

:func:`wholly_shaded_pixels` finds, for a sun direction, every pixel of the view that sees a
known surface in the model's shadow (facing away from the sun, or a ray toward it blocked by
the real proxies: the geometry ``in_sun`` casts against), and keeps those whose neighbours
within ``margin_px`` are in shadow too (an eroded shadow mask in image space: the pixel's
whole footprint, and what JPEG's blocks and the lens mix into it, is shade). Such a pixel is
read alone, not as a patch (its neighbours may lie on other faces of other tilts), and its
model is its own centre's: the surface point, normal, open sky and bounce of
``server.scenesamples.samples_at``.

Directions are site-frame unit vectors (+X east, +Y up, -Z north).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from server.scenesamples import SURFACE_OFFSET_M, PinholeView

FRONT_COS = 0.05  # a surface seen more grazing than this (cosine to the ray) is not used


@dataclass(frozen=True)
class ViewHits:
    """What every pixel of a view sees of the mesh (computed once per view).

    face : (H, W) int, the face through each pixel's centre, -1 for none (or one seen from
    behind or at a grazing angle); points_m : (H, W, 3) site points (NaN where none);
    normals : (H, W, 3) unit face normals.
    """

    face: np.ndarray
    points_m: np.ndarray
    normals: np.ndarray


def view_hits(mesh: trimesh.Trimesh, view: PinholeView, hit) -> ViewHits:
    """:class:`ViewHits` of ``view`` against ``mesh`` (``hit``: its intersector)."""
    ys, xs = np.mgrid[0:view.height, 0:view.width]
    centres = np.column_stack([xs.ravel(), ys.ravel()]).astype(float) + 0.5
    origins, dirs = view.rays(centres)
    loc, ray_idx, tri = hit.intersects_location(origins, dirs, multiple_hits=False)
    face = np.full(len(centres), -1)
    face[ray_idx] = tri
    points = np.full((len(centres), 3), np.nan)
    points[ray_idx] = loc
    normals = mesh.face_normals[np.maximum(face, 0)]
    front = np.einsum("ij,ij->i", normals, dirs) < -FRONT_COS
    face[~front] = -1
    points[~front] = np.nan
    shape = (view.height, view.width)
    return ViewHits(face.reshape(shape), points.reshape(shape + (3,)),
                    normals.reshape(shape + (3,)))


def wholly_shaded_pixels(hits: ViewHits, hit, sun_dir: np.ndarray, margin_px: int = 1,
                         border_px: int = 2) -> np.ndarray:
    """(k, 2) int pixel (column, row) of the view that see a known surface in the model's
    shadow for the unit ``sun_dir`` (3,), with every pixel within ``margin_px`` of them
    (a square) seeing one in shadow too, and at least ``border_px`` from the image's edge.
    None (an empty (0, 2)) when the sun is down: the sun is not in question then."""
    sun_dir = np.asarray(sun_dir, float)
    height, width = hits.face.shape
    seen = hits.face >= 0
    if sun_dir[1] <= 0.0 or not seen.any():
        return np.zeros((0, 2), int)
    facing = seen & (hits.normals @ sun_dir > 0.0)
    shaded = seen & ~facing
    idx = np.argwhere(facing)
    start = hits.points_m[idx[:, 0], idx[:, 1]] + SURFACE_OFFSET_M * hits.normals[
        idx[:, 0], idx[:, 1]]
    blocked = hit.intersects_any(start, np.broadcast_to(sun_dir, start.shape))
    shaded[idx[blocked, 0], idx[blocked, 1]] = True
    wholly = shaded.copy()
    r = int(margin_px)
    padded = np.pad(shaded, r, constant_values=False)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            wholly &= padded[r + dy:r + dy + height, r + dx:r + dx + width]
    b = max(int(border_px), r)
    wholly[:b] = wholly[-b:] = False
    wholly[:, :b] = wholly[:, -b:] = False
    rows, cols = np.nonzero(wholly)
    return np.column_stack([cols, rows])


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

Only pixels near the model's shadow are cast against the mesh: those in the image of a bounding
box of one of the mesh's connected parts (:func:`part_boxes`) swept away from the sun
(:func:`box_reach_mask`) and no higher than its top. A ray from any other pixel misses every
box, so every face: the pixels found are the same as casting every pixel's ray.

Directions are site-frame unit vectors (+X east, +Y up, -Z north).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import trimesh

from server.scenesamples import SURFACE_OFFSET_M, PinholeView

FRONT_COS = 0.05  # a surface seen more grazing than this (cosine to the ray) is not used


@dataclass(frozen=True)
class ViewHits:
    """What every pixel of a view sees of the mesh (computed once per view).

    face : (H, W) int, the face through each pixel's centre, -1 for none (or one seen from
    behind or at a grazing angle); points_m : (H, W, 3) site points (NaN where none);
    normals : (H, W, 3) unit face normals; boxes_m : (B, 2, 3) the mesh's parts' bounding
    boxes (:func:`part_boxes`) and view : the view, or None: every sunward pixel is cast.
    """

    face: np.ndarray
    points_m: np.ndarray
    normals: np.ndarray
    boxes_m: np.ndarray | None = None
    view: PinholeView | None = None


# Bounding boxes are grown by this much (m) so that a ray grazing a box's face in floating point
# is still cast.
BOX_PAD_M = 1e-3


def part_boxes(mesh: trimesh.Trimesh) -> np.ndarray:
    """(B, 2, 3) min and max corners (site m) of the mesh's connected parts (faces sharing
    edges), each grown by ``BOX_PAD_M``."""
    parts = trimesh.graph.connected_components(mesh.face_adjacency,
                                               nodes=np.arange(len(mesh.faces)))
    corners = [mesh.vertices[mesh.faces[np.asarray(part, int)]].reshape(-1, 3)
               for part in parts]
    return np.array([[c.min(axis=0) - BOX_PAD_M, c.max(axis=0) + BOX_PAD_M]
                     for c in corners]).reshape(-1, 2, 3)


def sunward_near_parts(hits: ViewHits, view: PinholeView, idx: np.ndarray, start_m: np.ndarray,
                       sun_dir: np.ndarray) -> np.ndarray:
    """(k,) bool of the pixels ``idx`` (k, 2) (row, column) whose rays from ``start_m``
    (k, 3) toward the unit ``sun_dir`` (3,; up) could meet a face: they start no higher than
    the top of a part's box (:func:`part_boxes`; a ray toward the sun climbs) and in the image
    of that box swept along ``-sun_dir`` down to below every start (a convex solid: its image
    is the convex hull of its 16 corners' images), grown by a pixel. A box partly behind the
    camera, or far outside the image, reaches every pixel. Every other ray misses every face.
    """
    sun_dir = np.asarray(sun_dir, float)
    height, width = view.height, view.width
    start_y = np.full((height, width), np.inf)
    start_y[idx[:, 0], idx[:, 1]] = start_m[:, 1]
    floor_y = float(min(start_m[:, 1].min(), hits.boxes_m[:, 0, 1].min())) - 1.0
    rot, eye = view.world_from_camera[:3, :3], view.world_from_camera[:3, 3]
    near = np.zeros((height, width), bool)
    limit = 1e5  # pixels: a hull beyond this is not rasterised (int overflow): all reached
    for lo, hi in hits.boxes_m:
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        drop = (corners[:, 1] - floor_y) / sun_dir[1]
        cam = (np.vstack([corners, corners - drop[:, None] * sun_dir]) - eye) @ rot
        uv = (cam @ view.K.T)[:, :2] / np.maximum(cam[:, 2:3], 1e-12) - 0.5  # centres at ints
        if np.any(cam[:, 2] <= 1e-6) or np.any(np.abs(uv) > limit):
            near |= start_y <= hi[1]
            continue
        x0, y0 = (max(int(np.floor(v)) - 1, 0) for v in uv.min(axis=0))
        x1, y1 = (int(np.ceil(v)) + 2 for v in uv.max(axis=0))
        x1, y1 = min(x1, width), min(y1, height)
        if x0 >= x1 or y0 >= y1:
            continue
        # rasterised in the box's own rectangle of the image, a pixel's margin about it
        local = np.zeros((y1 - y0 + 2, x1 - x0 + 2), np.uint8)
        pts = np.round((uv - [x0 - 1, y0 - 1]) * 16.0).astype(np.int32)
        cv2.fillConvexPoly(local, cv2.convexHull(pts), 1, lineType=cv2.LINE_8, shift=4)
        local = cv2.dilate(local, np.ones((3, 3), np.uint8))[1:-1, 1:-1].astype(bool)
        near[y0:y1, x0:x1] |= local & (start_y[y0:y1, x0:x1] <= hi[1])
    return near[idx[:, 0], idx[:, 1]]


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
                    normals.reshape(shape + (3,)), part_boxes(mesh), view)


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
    if hits.boxes_m is not None and hits.view is not None and len(idx):
        # a ray that meets no part's box meets no face: only the rest are cast
        near = sunward_near_parts(hits, hits.view, idx, start, sun_dir)
        idx, start = idx[near], start[near]
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


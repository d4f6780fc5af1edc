"""Fixed viewpoints (Sato's Camera A): where each pixel's ray lands, with and without the
virtual objects.

For every pixel of a view the baker needs, per light ``i`` (Sato Eq. 7-9):

- ``O_i``: radiance seen with the virtual objects present (the *object image*),
- ``S_i``: radiance seen without them (the *surface image*),
- the *mask*: whether the pixel sees a virtual object first.

A pixel whose ray meets a surface becomes a receiver point (its radiance is
``albedo / pi * E_i`` at that point); one that looks below the horizon past all geometry sees the
open ground beyond the site. Pixels that see the sky are left out of ``O`` and ``S`` (zero) and
marked 128 in the mask: a client that has no live camera draws the sky itself from the light
vector as ``sum_i r_i phi_i(w)``, with ``phi_i`` the smooth partition of unity over the patch
centroids of :func:`sky_weights` (a smooth sky through the measured patch radiances rather than
a mosaic of triangles; a uniform sky stays exactly uniform). Keeping the sky's unit radiances
out of the stacks matters for compression: next to them the surfaces' radiances are hundreds of
times smaller and would drown in 8-bit quantization.

Camera coordinates follow OpenCV: +X right, +Y down, +Z forward.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bake.raytrace import RayScene
from daylit.spherical import normalize


@dataclass
class ViewHits:
    """Where one configuration's camera rays land.

    Attributes
    ----------
    surface : (P,) int, flat pixel indices that hit a surface
    faces : (P,) int, the global face each of those sees
    points, normals, albedo : (P, 3) the hit point, the face normal facing the camera, albedo
    virtual : (P,) bool, whether the surface is virtual
    depth_m : (P,) distance along the optical axis
    sky : (Q,) int, flat pixel indices that see the sky above the horizon
    sky_dirs : (Q, 3) their directions
    open_ground : (R,) int, pixels that look below the horizon past all geometry
    """

    surface: np.ndarray
    faces: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    virtual: np.ndarray
    depth_m: np.ndarray
    sky: np.ndarray
    sky_dirs: np.ndarray
    open_ground: np.ndarray


def pixel_rays(view) -> tuple[np.ndarray, np.ndarray]:
    """World-frame origins and unit directions through every pixel centre, (H*W, 3) each."""
    ys, xs = np.mgrid[0 : view.height, 0 : view.width]
    pix = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5, np.ones(xs.size)], axis=1)
    cam_dirs = pix @ np.linalg.inv(view.K).T
    R = view.world_from_camera[:3, :3]
    dirs = normalize(cam_dirs @ R.T)
    origins = np.broadcast_to(view.world_from_camera[:3, 3], dirs.shape).copy()
    return origins, dirs


def trace_view(view, scene: RayScene, face_ids: np.ndarray, geometry) -> ViewHits:
    """Cast one ray per pixel centre into ``scene`` (a light configuration's geometry)."""
    origins, dirs = pixel_rays(view)
    face, distance = scene.first_hit(origins, dirs)
    hit = face >= 0
    surface = np.flatnonzero(hit)
    global_face = face_ids[face[hit]]
    normals = geometry.face_normals[global_face]
    # Show the side facing the camera.
    flip = np.einsum("ij,ij->i", normals, dirs[hit]) > 0.0
    normals[flip] *= -1.0
    points = origins[hit] + distance[hit, None] * dirs[hit]
    forward = view.world_from_camera[:3, 2]
    depth = (points - origins[hit]) @ forward
    sky = np.flatnonzero(~hit & (dirs[:, 1] >= 0.0))
    open_ground = np.flatnonzero(~hit & (dirs[:, 1] < 0.0))
    return ViewHits(
        surface=surface,
        faces=global_face,
        points=points,
        normals=normals,
        albedo=geometry.albedo[global_face],
        virtual=geometry.virtual[global_face],
        depth_m=depth,
        sky=sky,
        sky_dirs=dirs[sky],
        open_ground=open_ground,
    )


def sky_weights(dirs: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Smooth partition of unity over the patches, ``(Q, n)``, rows summing to 1.

    Gaussian in the angle to each patch centroid, about as wide as a patch.
    """
    n = len(centroids)
    width = 0.7 * np.sqrt(2.0 * np.pi / n)  # ~ a patch's angular radius, radians
    logits = (dirs @ centroids.T - 1.0) / (width * width)
    logits -= logits.max(axis=1, keepdims=True)
    w = np.exp(logits)
    return w / w.sum(axis=1, keepdims=True)


def radiance_image(
    view,
    hits: ViewHits,
    E_surface: np.ndarray,
    up_irradiance: np.ndarray,
    ground_albedo: np.ndarray,
) -> np.ndarray:
    """Assemble a view's basis radiance stack, (H, W, n, 3) float32; zero on the sky.

    ``E_surface`` (P, n, 3) is the basis irradiance at ``hits.points``.
    """
    n = E_surface.shape[1] if len(E_surface) else len(up_irradiance)
    image = np.zeros((view.height * view.width, n, 3), dtype=np.float32)
    image[hits.surface] = hits.albedo[:, None, :] / np.pi * E_surface
    image[hits.open_ground] = (ground_albedo[None, :] / np.pi) * up_irradiance[:, None]
    return image.reshape(view.height, view.width, n, 3)


MASK_REAL, MASK_SKY, MASK_VIRTUAL = 0, 128, 255


def mask_image(view, hits: ViewHits) -> np.ndarray:
    """(H, W) uint8: 255 where the pixel sees a virtual object first, 128 where it sees the sky
    (above the horizon, past all geometry), 0 where it sees a real surface or the ground."""
    mask = np.full(view.height * view.width, MASK_REAL, dtype=np.uint8)
    mask[hits.sky] = MASK_SKY
    mask[hits.surface[hits.virtual]] = MASK_VIRTUAL
    return mask.reshape(view.height, view.width)


def virtual_depth_image(view, hits: ViewHits) -> np.ndarray:
    """(H, W) float32: depth (m, along the optical axis) of the virtual surface each pixel
    sees first, +inf where it sees none. Occlusion by visitors compares against this."""
    depth = np.full(view.height * view.width, np.inf, dtype=np.float32)
    depth[hits.surface[hits.virtual]] = hits.depth_m[hits.virtual]
    return depth.reshape(view.height, view.width)

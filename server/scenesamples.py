"""What a fixed view sees of the real site, for the scene estimate (server.sceneestimate).

A site camera's view (:class:`PinholeView`) and the pool of pixels of known diffuse surfaces
it sees (:func:`prepare_samples` -> :class:`SceneSamples`): per pixel the surface point, its
normal and albedo, which directions of its hemisphere see open sky and what the others hit
(the one-bounce terms). All of it depends on the view and the real proxies only, so it is
computed once per view; the sun's part (in sun or not) is the estimator's.

Directions are site-frame unit vectors (+X east, +Y up, -Z north). Cameras follow the
manifest's views: 3x3 ``K`` (OpenCV: +X right, +Y down, +Z forward, pixel centres at +0.5)
and 4x4 ``world_from_camera``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh

from daylit.spherical import normalize
from server.skyshape import upper_hemisphere_grid
from server.surfacescale import surfaces_by_albedo

SURFACE_OFFSET_M = 0.01  # rays leave a surface this far along its normal
# Zenith steps of the fixed sky grid each sample's open sky is found on (twice as many in
# azimuth: 3.75 degree cells, 1152 directions). The sky term is the model sky's radiance over
# it: a clear sky's circumsolar peak is some 20 degrees wide, and the 96 cosine-distributed
# directions of the hemisphere (the same for every sample of one tilt) put 0.93 to 1.06 of the
# horizontal irradiance on an open horizontal plane, depending on where the sun fell between
# them, and misread what a tree or a building blocks near the sun (docs/server.md).
SKY_GRID_STEPS = 24


class SceneEstimateError(ValueError):
    """The view cannot support an estimate (no known surface in it, bad inputs)."""


@dataclass(frozen=True)
class PinholeView:
    """A site camera: ``K`` (3, 3) pixels, ``world_from_camera`` (4, 4), size in pixels."""

    K: np.ndarray
    world_from_camera: np.ndarray
    width: int
    height: int

    @classmethod
    def from_manifest(cls, view: dict) -> PinholeView:
        """From a manifest ``views[]`` entry (docs/manifest.md)."""
        return cls(np.asarray(view["K"], float), np.asarray(view["world_from_camera"], float),
                   int(view["width"]), int(view["height"]))

    def rays(self, pixels_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World origins and unit directions (m, 3) through pixel positions ``(m, 2)`` (x, y;
        a pixel's centre is at its index + 0.5)."""
        pix = np.column_stack([pixels_xy, np.ones(len(pixels_xy))])
        cam = pix @ np.linalg.inv(self.K).T
        dirs = normalize(cam @ self.world_from_camera[:3, :3].T)
        origins = np.broadcast_to(self.world_from_camera[:3, 3], dirs.shape).copy()
        return origins, dirs


def cosine_directions(count: int, seed: int = 0, sets: int | None = None) -> np.ndarray:
    """``count`` cosine-distributed unit directions (count, 3) about +Z (stratified); with
    ``sets``, that many independently jittered sets (sets, count, 3)."""
    rng = np.random.default_rng(seed)
    side = max(1, int(math.sqrt(count)))
    shape = (count,) if sets is None else (sets, count)
    u = (np.arange(count) % side + rng.random(shape)) / side
    v = (np.arange(count) // side + rng.random(shape)) / math.ceil(count / side)
    r = np.sqrt(np.clip(u, 0.0, 1.0))
    phi = 2.0 * math.pi * np.clip(v, 0.0, 1.0)
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r * r)], axis=-1)


def _frames_about(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (m, 3) each, orthogonal to the unit ``normals`` (m, 3)."""
    helper = np.where(np.abs(normals[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    t = normalize(np.cross(helper, normals))
    return t, np.cross(normals, t)


@dataclass
class SceneSamples:
    """The pool of known, diffuse surface pixels a view sees, and what the geometry says of
    them (computed once per view).

    Attributes (m samples, K hemisphere directions)
    ----------
    pixels_xy : (m, 2) int pixel column and row
    points_m : (m, 3) site points; normals : (m, 3) unit, facing the camera
    albedo : (m, 3) RGB albedo of the surface each pixel sees
    hemisphere_dirs : (m, K, 3) cosine-distributed directions about each normal
    sky_visible : (m, K) bool, the direction sees open sky (nothing hit, above the horizon)
    bounce_points_m : (n, 3) what the other directions hit (n of them, all samples);
    bounce_normals : (n, 3) unit; bounce_albedo : (n, 3); bounce_sample : (n,) int, the sample
    each belongs to (directions below the horizon that hit nothing: open ground far away,
    normal +Y, point NaN)
    """

    pixels_xy: np.ndarray
    points_m: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    hemisphere_dirs: np.ndarray
    sky_visible: np.ndarray
    bounce_points_m: np.ndarray
    bounce_normals: np.ndarray
    bounce_albedo: np.ndarray
    bounce_sample: np.ndarray
    surface: np.ndarray
    sky_grid_dirs: np.ndarray
    sky_grid_sr: np.ndarray
    sky_weight: np.ndarray

    @property
    def sky_view(self) -> np.ndarray:
        """(m,) cosine-weighted fraction of each hemisphere that sees open sky (on the sky
        grid: an isotropic sky's irradiance per unit of an open horizontal plane's)."""
        return self.sky_weight.sum(axis=1, dtype=np.float64) / math.pi

    def bounce_terms(self, bounce_lit: np.ndarray, bounce_sky: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per sample (m, 3) RGB, one bounce, per unit sun normal irradiance and per unit sky
        horizontal irradiance: ``mean_K rho_h cos_h in_sun_h`` and ``mean_K rho_h E_h(n_h)``
        with ``E_h`` the sky's irradiance on the bounce surface's tilt per unit horizontal
        irradiance, ``bounce_sky`` (n,) (default an isotropic sky's ``(1 + n_hy) / 2``); and
        the fraction of each hemisphere that bounces. ``bounce_lit`` (n,) float:
        ``cos_h * in_sun_h`` of each bounce point."""
        m, k = self.sky_visible.shape
        view = 0.5 * (1.0 + self.bounce_normals[:, 1]) if bounce_sky is None else bounce_sky
        sun = np.column_stack([np.bincount(self.bounce_sample, self.bounce_albedo[:, c]
                                           * bounce_lit, minlength=m) for c in range(3)])
        sky = np.column_stack([np.bincount(self.bounce_sample, self.bounce_albedo[:, c] * view,
                                           minlength=m) for c in range(3)])
        return sun / k, sky / k, np.bincount(self.bounce_sample, minlength=m) / k

    @cached_property
    def bounce_normal_groups(self) -> tuple[np.ndarray, np.ndarray]:
        """(u, 3) the distinct bounce normals and (n,) each bounce's index into them (the
        faces' normals: a few hundred distinct among up to 10^5 bounces, so a sky's tilted
        irradiance is evaluated once for each)."""
        unique, inverse = np.unique(self.bounce_normals, axis=0, return_inverse=True)
        return unique, inverse.reshape(-1)


def patch_points_m(samples: SceneSamples, view: PinholeView, patch_px: int) -> np.ndarray:
    """(m, P, 3) site points seen through the ``P = (2 patch_px + 1)^2`` pixel centres of each
    sample's patch (what a sample's read averages), on the sample's plane (the pool keeps
    patches on one plane)."""
    dy, dx = np.mgrid[-patch_px:patch_px + 1, -patch_px:patch_px + 1]
    offsets = np.column_stack([dx.ravel(), dy.ravel()]).astype(float)
    k = len(offsets)
    pixels = (samples.pixels_xy[:, None, :] + 0.5 + offsets[None]).reshape(-1, 2)
    origins, dirs = view.rays(pixels)
    plane_point = np.repeat(samples.points_m, k, axis=0)
    plane_normal = np.repeat(samples.normals, k, axis=0)
    t = np.einsum("ij,ij->i", plane_point - origins, plane_normal) / np.einsum(
        "ij,ij->i", dirs, plane_normal)
    return (origins + t[:, None] * dirs).reshape(-1, k, 3)


def intersector(mesh: trimesh.Trimesh):
    """trimesh's ray intersector for ``mesh``: Embree's where installed."""
    return trimesh.ray.ray_pyembree.RayMeshIntersector(mesh) if trimesh.ray.has_embree \
        else trimesh.ray.ray_triangle.RayMeshIntersector(mesh)


def prepare_samples(mesh: trimesh.Trimesh, face_albedo: np.ndarray, view: PinholeView,
                    count: int = 3000, hemisphere_count: int = 96, seed: int = 0,
                    edge_px: float = 1.5, environment_albedo: float = 0.2) -> SceneSamples:
    """Pick up to ``count`` random pixels of ``view`` that see a face of ``mesh`` (the real
    proxies, ground included) away from any edge, with what the geometry says of them.

    ``face_albedo`` (F, 3): each face's RGB albedo. A pixel is kept when the rays through its
    corners (``edge_px`` away) hit faces of the same plane as its centre (so a 3 x 3 mean of
    it reads one surface), and its surface faces the camera.
    """
    face_albedo = np.asarray(face_albedo, float)
    if face_albedo.shape != (len(mesh.faces), 3):
        raise SceneEstimateError(f"face_albedo has shape {face_albedo.shape}, the mesh "
                                 f"{len(mesh.faces)} faces")
    rng = np.random.default_rng(seed)
    hit = intersector(mesh)
    margin = 2
    tries = count * 3
    xs = rng.integers(margin, view.width - margin, tries)
    ys = rng.integers(margin, view.height - margin, tries)
    centres = np.column_stack([xs, ys]).astype(float) + 0.5
    origins, dirs = view.rays(centres)
    face = hit.intersects_first(origins, dirs)
    ok = face >= 0
    face_normals = mesh.face_normals[np.maximum(face, 0)]
    ok &= np.einsum("ij,ij->i", face_normals, dirs) < -0.05  # seen from the front
    for dx, dy in ((-1, -1), (1, -1), (-1, 1), (1, 1)):
        o, d = view.rays(centres + edge_px * np.array([dx, dy]))
        f = hit.intersects_first(o, d)
        same = f >= 0
        same &= np.einsum("ij,ij->i", mesh.face_normals[np.maximum(f, 0)], face_normals) > 0.999
        # same plane: the corner's hit lies on the centre face's plane
        loc, ray_idx, _ = hit.intersects_location(o[ok & same], d[ok & same], multiple_hits=False)
        keep = np.zeros(len(f), bool)
        if len(ray_idx):
            sel = np.flatnonzero(ok & same)[ray_idx]
            v0 = mesh.vertices[mesh.faces[face[sel], 0]]
            keep[sel] = np.abs(np.einsum("ij,ij->i", loc - v0, face_normals[sel])) < 0.02
        ok &= keep
    idx = np.flatnonzero(ok)[:count]
    if len(idx) == 0:
        raise SceneEstimateError("the view sees no surface of the real proxies")
    return samples_at(mesh, face_albedo, view, np.column_stack([xs[idx], ys[idx]]), hit,
                      hemisphere_count, seed, environment_albedo)


def samples_at(mesh: trimesh.Trimesh, face_albedo: np.ndarray, view: PinholeView,
               pixels_xy: np.ndarray, hit=None, hemisphere_count: int = 96, seed: int = 0,
               environment_albedo: float = 0.2) -> SceneSamples:
    """The samples of given pixels ``pixels_xy`` (m, 2) int (column, row) of ``view``, each of
    which must see a face of ``mesh`` from its front (the caller's choice: no edge check here):
    what the geometry says of the surface through each pixel's centre. ``hit``: the mesh's
    intersector (made when None)."""
    face_albedo = np.asarray(face_albedo, float)
    hit = intersector(mesh) if hit is None else hit
    pixels_xy = np.asarray(pixels_xy, int).reshape(-1, 2)
    origins, dirs = view.rays(pixels_xy.astype(float) + 0.5)
    face = hit.intersects_first(origins, dirs)
    if np.any(face < 0):
        raise SceneEstimateError("a pixel given to samples_at sees no face of the mesh")
    # Hit points of the kept centres.
    loc, ray_idx, _ = hit.intersects_location(origins, dirs, multiple_hits=False)
    points = np.empty((len(pixels_xy), 3))
    points[ray_idx] = loc
    normals = mesh.face_normals[face]
    t, b = _frames_about(normals)
    # each sample its own jittered set: one set shared by all samples of a tilt put the
    # same quadrature error on all of them (a bounce from a shadow's edge seen through a few
    # directions), which the fit reads as sky (up to 18 % between pools, docs/server.md)
    local = cosine_directions(hemisphere_count, seed + 1, sets=len(pixels_xy))
    hemi = (local[:, :, 0:1] * t[:, None] + local[:, :, 1:2] * b[:, None]
            + local[:, :, 2:3] * normals[:, None])
    m, k = hemi.shape[:2]
    start = np.repeat(points + SURFACE_OFFSET_M * normals, k, axis=0)
    flat = hemi.reshape(-1, 3)
    first = hit.intersects_first(start, flat)
    blocked = (first >= 0).reshape(m, k)
    sky_visible = ~blocked & (hemi[..., 1] > 0.0)
    # What the other directions see: a face (where it is hit), or far ground.
    hits = np.flatnonzero(first >= 0)
    loc, ray_idx, _ = hit.intersects_location(start[hits], flat[hits], multiple_hits=False)
    hit_points = np.full((len(hits), 3), np.nan)
    hit_points[ray_idx] = loc
    found = np.isfinite(hit_points[:, 0])
    hits, hit_points = hits[found], hit_points[found]
    far = np.flatnonzero((first < 0) & (flat[:, 1] <= 0.0))
    bounce_rays = np.concatenate([hits, far])
    env = np.full(3, environment_albedo)
    grid_dirs, grid_sr, sky_weight = open_sky_weights(hit, points, normals)
    return SceneSamples(
        pixels_xy=pixels_xy,
        points_m=points, normals=normals, albedo=face_albedo[face],
        hemisphere_dirs=hemi, sky_visible=sky_visible,
        bounce_points_m=np.vstack([hit_points, np.full((len(far), 3), np.nan)]),
        bounce_normals=np.vstack([mesh.face_normals[first[hits]],
                                  np.tile([0.0, 1.0, 0.0], (len(far), 1))]),
        bounce_albedo=np.vstack([face_albedo[first[hits]], np.tile(env, (len(far), 1))]),
        bounce_sample=bounce_rays // k,
        surface=surfaces_by_albedo(face_albedo)[face],
        sky_grid_dirs=grid_dirs, sky_grid_sr=grid_sr, sky_weight=sky_weight,
    )


def open_sky_weights(hit, points_m: np.ndarray, normals: np.ndarray,
                     steps: int = SKY_GRID_STEPS
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sky grid (``upper_hemisphere_grid(steps)``: (G, 3) directions, (G,) solid angles
    sr) and (m, G) float32
    each cell's ``d_omega * cos`` to the unit ``normals`` (m, 3) where a ray from ``points_m``
    (m, 3) that way hits nothing of the mesh (``hit``: its intersector), else 0."""
    dirs, d_omega = upper_hemisphere_grid(steps)
    cos = normals @ dirs.T
    front = np.argwhere(cos > 0.0)
    start = points_m[front[:, 0]] + SURFACE_OFFSET_M * normals[front[:, 0]]
    blocked = np.zeros(len(front), bool)
    chunk = 500_000
    for k in range(0, len(front), chunk):
        blocked[k:k + chunk] = hit.intersects_any(start[k:k + chunk],
                                                  dirs[front[k:k + chunk, 1]])
    weight = np.zeros(cos.shape, np.float32)
    open_ = front[~blocked]
    weight[open_[:, 0], open_[:, 1]] = (cos[open_[:, 0], open_[:, 1]]
                                        * d_omega[open_[:, 1]])
    return dirs, d_omega, weight

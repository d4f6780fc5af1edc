"""Spherical triangles: the geometry of sky patches.

A sky patch is a spherical triangle given by three unit vertices whose edges are great-circle
arcs. Everything here is vectorized numpy and knows nothing about scenes or cameras, so the
baker (which builds the dome), the server (which reads it back from ``manifest.json``) and the
tests can all share it.

Conventions
-----------
- Triangles are arrays of shape ``(n, 3, 3)``: ``tris[i, j]`` is vertex ``j`` of triangle ``i``,
  a unit vector in the world frame (+Y up). Vertices are counter-clockwise seen from outside
  the sphere, i.e. ``det(a, b, c) > 0``.
- Directions are arrays of shape ``(m, 3)``, unit length.
- Solid angles are in steradians.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def normalize(v: np.ndarray) -> np.ndarray:
    """Unit vectors along the last axis of ``v`` (any leading shape)."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def solid_angle(tris: np.ndarray) -> np.ndarray:
    """Solid angle of each spherical triangle, shape ``(n,)``, in sr.

    Van Oosterom & Strackee (1983): ``tan(omega/2) = |a.(b x c)| / (1 + a.b + b.c + c.a)``,
    exact for great-circle triangles and well conditioned for small ones.
    """
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    numerator = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    denominator = (
        1.0
        + np.einsum("ij,ij->i", a, b)
        + np.einsum("ij,ij->i", b, c)
        + np.einsum("ij,ij->i", c, a)
    )
    return 2.0 * np.arctan2(numerator, denominator)


def centroid_direction(tris: np.ndarray) -> np.ndarray:
    """Unit direction through the planar centroid of each triangle, shape ``(n, 3)``."""
    return normalize(tris.mean(axis=1))


def contains(tris: np.ndarray, dirs: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
    """Whether each direction lies inside each triangle, shape ``(m, n)`` bool.

    A direction is inside when it is on the inner side of the three great-circle planes of the
    edges; ``tolerance`` widens (positive) or narrows (negative) every edge.
    """
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    inside = np.ones((dirs.shape[0], tris.shape[0]), dtype=bool)
    for p, q in ((a, b), (b, c), (c, a)):
        edge_normal = normalize(np.cross(p, q))  # (n, 3), points into the triangle
        inside &= dirs @ edge_normal.T >= -tolerance
    # The three planes also admit the antipodal triangle; keep the near side only.
    inside &= dirs @ centroid_direction(tris).T > 0.0
    return inside


class PatchLookup:
    """Finds the patch that contains each direction.

    Builds a k-d tree on patch centroids; each query tests the few nearest patches exactly and
    falls back to testing every patch for the rare direction none of them contains.

    Parameters
    ----------
    tris : (n, 3, 3) float
        Unit vertices of the patches, counter-clockwise from outside.
    """

    def __init__(self, tris: np.ndarray, candidates: int = 8):
        self.tris = np.asarray(tris, dtype=np.float64)
        self.edge_normals = np.stack(
            [normalize(np.cross(self.tris[:, j], self.tris[:, (j + 1) % 3])) for j in range(3)],
            axis=1,
        )  # (n, 3 edges, 3)
        self.centroids = centroid_direction(self.tris)
        self.tree = cKDTree(self.centroids)
        self.candidates = min(candidates, len(self.tris))

    def _inside(self, dirs: np.ndarray, patch: np.ndarray) -> np.ndarray:
        """Exact test of ``dirs[k]`` against ``patch[k]`` (broadcast over trailing axes)."""
        normals = self.edge_normals[patch]  # (..., 3, 3)
        side = np.einsum("...ej,...j->...e", normals, dirs)
        near = np.einsum("...j,...j->...", self.centroids[patch], dirs) > 0.0
        return np.all(side >= 0.0, axis=-1) & near

    def __call__(self, dirs: np.ndarray) -> np.ndarray:
        """Index of the patch containing each direction, shape ``(m,)``; -1 below the horizon.

        Directions exactly on a shared edge go to the lowest-numbered candidate that
        contains them, so every direction gets exactly one patch.
        """
        dirs = np.asarray(dirs, dtype=np.float64)
        result = np.full(dirs.shape[0], -1, dtype=np.int64)
        above = dirs[:, 1] >= 0.0
        if not np.any(above):
            return result
        d = dirs[above]
        _, near = self.tree.query(d, k=self.candidates)
        near = near.reshape(len(d), -1)
        inside = self._inside(d[:, None, :], near)  # (m, k)
        # Ties on shared edges: prefer the smallest index among the containing candidates.
        masked = np.where(inside, near, np.iinfo(np.int64).max)
        best = masked.min(axis=1)
        found = best != np.iinfo(np.int64).max
        out = np.where(found, best, -1)
        missing = np.flatnonzero(~found)
        if missing.size:
            full = contains(self.tris, d[missing], tolerance=1e-12)
            has = full.any(axis=1)
            out[missing[has]] = np.argmax(full[has], axis=1)
        result[above] = out
        return result


def clipped_cosine_integral(tris: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance from each patch at unit radiance on surfaces facing ``normals``.

    Computes ``integral over (patch and hemisphere of n) of max(0, n . w) dw`` exactly with
    Lambert's formula for polygons, ``E = 1/2 sum_k theta_k (n . u_k)``, after clipping each
    patch to the surface's upper hemisphere (the clipped part is again a spherical polygon
    whose extra edge runs along the surface's horizon).

    Parameters
    ----------
    tris : (n, 3, 3) float
        Patch vertices, counter-clockwise from outside.
    normals : (m, 3) float
        Unit surface normals.

    Returns
    -------
    (m, n) float
        Irradiance in W/m^2 per W/(m^2 sr) of patch radiance. Summed over a dome that tiles the
        upper hemisphere it is ``pi`` for an upward normal and ``pi/2`` for a vertical one.
    """
    tris = np.asarray(tris, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    n_patches = tris.shape[0]
    nrm = normals[:, None, :]  # (m, 1, 3)
    total = np.zeros((normals.shape[0], n_patches))
    # Exit (inside -> outside) and entry (outside -> inside) points on the horizon circle.
    exit_point = np.zeros((normals.shape[0], n_patches, 3))
    entry_point = np.zeros((normals.shape[0], n_patches, 3))
    for j in range(3):
        p = np.broadcast_to(tris[:, j], (normals.shape[0], n_patches, 3))
        q = np.broadcast_to(tris[:, (j + 1) % 3], (normals.shape[0], n_patches, 3))
        sp = np.einsum("mnj,mnj->mn", p, nrm * np.ones_like(p))
        sq = np.einsum("mnj,mnj->mn", q, nrm * np.ones_like(q))
        p_in, q_in = sp >= 0.0, sq >= 0.0
        # Where the edge crosses the horizon plane: a point of the great circle through p, q.
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(p_in != q_in, sp / (sp - sq), 0.0)
        crossing = normalize(p + t[..., None] * (q - p) + 1e-300)
        start = np.where(p_in[..., None], p, crossing)
        end = np.where(q_in[..., None], q, crossing)
        keep = p_in | q_in
        total += np.where(keep, _lambert_edge(start, end, nrm), 0.0)
        leaving = p_in & ~q_in
        entering = ~p_in & q_in
        exit_point = np.where(leaving[..., None], crossing, exit_point)
        entry_point = np.where(entering[..., None], crossing, entry_point)
    # The closing edge along the horizon, from where the boundary leaves to where it re-enters.
    clipped = np.any(exit_point != 0.0, axis=-1) & np.any(entry_point != 0.0, axis=-1)
    total += np.where(clipped, _lambert_edge(exit_point, entry_point, nrm), 0.0)
    return np.maximum(0.5 * total, 0.0)


def _lambert_edge(a: np.ndarray, b: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """One term ``theta (n . u)`` of Lambert's formula for the arc from ``a`` to ``b``."""
    cross = np.cross(a, b)
    sin_theta = np.linalg.norm(cross, axis=-1)
    cos_theta = np.einsum("...j,...j->...", a, b)
    theta = np.arctan2(sin_theta, cos_theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(sin_theta[..., None] > 1e-15, cross / sin_theta[..., None], 0.0)
    return theta * np.einsum("...j,...j->...", u, normal * np.ones_like(u))


def sample_triangles(tris: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions inside each patch from unit-square samples, with solid-angle weights.

    Points are placed uniformly on the flat triangle through the three vertices and projected
    onto the sphere; ``weight`` is proportional to the solid angle each sample stands for
    (``dw/dA = cos(alpha) / r^2``), so weighted sums are unbiased over the spherical patch.

    Parameters
    ----------
    tris : (n, 3, 3) float
    uv : (..., 2) float in [0, 1)
        Samples of the unit square; broadcast against the patch axis as ``(..., n, 2)``.

    Returns
    -------
    dirs : (..., n, 3) float, unit directions
    weight : (..., n) float, relative solid-angle weights (mean about 1 over a patch)
    """
    u = uv[..., 0]
    v = uv[..., 1]
    su = np.sqrt(u)
    w0, w1, w2 = 1.0 - su, su * (1.0 - v), su * v
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    point = w0[..., None] * a + w1[..., None] * b + w2[..., None] * c
    r2 = np.einsum("...j,...j->...", point, point)
    plane_normal = normalize(np.cross(b - a, c - a))  # (n, 3)
    r = np.sqrt(r2)
    dirs = point / r[..., None]
    # Distance of the flat triangle from the centre, over r^3: the projection's Jacobian.
    h = np.einsum("nj,nj->n", a, plane_normal)
    weight = h / (r2 * r)
    return dirs, weight


def sh9_basis(dirs: np.ndarray) -> np.ndarray:
    """Real spherical harmonics up to l = 2 at unit directions, shape ``(..., 9)``.

    Order and constants of Ramamoorthi & Hanrahan (2001), applied to the world-frame
    components ``(x, y, z)`` as they are: ``Y00, Y1-1 (y), Y10 (z), Y11 (x), Y2-2 (xy),
    Y2-1 (yz), Y20 (3z^2 - 1), Y21 (xz), Y22 (x^2 - y^2)``. Irradiance convolution is
    rotation invariant, so the choice of axes only has to agree between baker and client.
    """
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    return np.stack(
        [
            0.282095 * np.ones_like(x),
            0.488603 * y,
            0.488603 * z,
            0.488603 * x,
            1.092548 * x * y,
            1.092548 * y * z,
            0.315392 * (3.0 * z * z - 1.0),
            1.092548 * x * z,
            0.546274 * (x * x - y * y),
        ],
        axis=-1,
    )


def patch_sh9(tris: np.ndarray, samples_per_side: int = 16) -> np.ndarray:
    """SH projection of unit radiance over each patch, ``integral_patch Y_lm dw``: ``(n, 9)``."""
    k = samples_per_side
    grid = (np.arange(k) + 0.5) / k
    uv = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 1, 2)
    dirs, weight = sample_triangles(tris, np.broadcast_to(uv, (k * k, tris.shape[0], 2)))
    mean = np.einsum("sn,snk->nk", weight, sh9_basis(dirs)) / weight.sum(axis=0)[:, None]
    return mean * solid_angle(tris)[:, None]

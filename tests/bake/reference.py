"""An independent brute-force renderer: the oracle for the baker's linearity test.

It shares no code with ``bake.irradiance``: directions in a patch come from Arvo's (1995)
uniform spherical-triangle sampling instead of projected flat-triangle samples, visibility from
trimesh's ray API instead of our Embree wrapper, and the bounce is traced recursively (one
level) instead of through a cache. It is slow and exact in expectation.
"""

from __future__ import annotations

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

OFFSET_M = 2e-3


def arvo_sample(tri: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Uniform directions in a spherical triangle ``tri`` (3, 3) from ``xi`` (m, 2) in [0,1)."""
    A, B, C = tri

    def angle_at(P, Q, R):
        tq = Q - (P @ Q) * P
        tr = R - (P @ R) * P
        return np.arccos(np.clip(tq @ tr / np.linalg.norm(tq) / np.linalg.norm(tr), -1, 1))

    alpha, beta, gamma = angle_at(A, B, C), angle_at(B, C, A), angle_at(C, A, B)
    area = alpha + beta + gamma - np.pi
    cos_c = A @ B
    sub = xi[:, 0] * area
    s, t = np.sin(sub - alpha), np.cos(sub - alpha)
    u = t - np.cos(alpha)
    v = s + np.sin(alpha) * cos_c
    q = ((v * t - u * s) * np.cos(alpha) - v) / ((v * s + u * t) * np.sin(alpha))
    perp = C - (C @ A) * A
    perp /= np.linalg.norm(perp)
    c_hat = q[:, None] * A + np.sqrt(np.clip(1 - q * q, 0, 1))[:, None] * perp
    z = 1.0 - xi[:, 1] * (1.0 - c_hat @ B)
    perp2 = c_hat - (c_hat @ B)[:, None] * B
    perp2 /= np.linalg.norm(perp2, axis=1, keepdims=True)
    return z[:, None] * B + np.sqrt(np.clip(1 - z * z, 0, 1))[:, None] * perp2


def spherical_area(tri: np.ndarray) -> float:
    a, b, c = tri
    num = abs(a @ np.cross(b, c))
    return 2.0 * np.arctan2(num, 1 + a @ b + b @ c + c @ a)


class ReferenceRenderer:
    """Irradiance at a point under a piecewise-constant sky (one radiance per dome patch).

    Parameters
    ----------
    meshes : list of (trimesh.Trimesh, albedo RGB)
        All blocking, reflecting geometry (ground included).
    patches : (n, 3, 3) dome triangles; radiance : (n, 3) per patch
    ground_albedo : RGB of the open ground beyond the geometry (rays leaving downward)
    """

    def __init__(self, meshes, patches, radiance, ground_albedo, rng):
        self.mesh = trimesh.util.concatenate([m for m, _ in meshes])
        self.albedo = np.concatenate([np.tile(a, (len(m.faces), 1)) for m, a in meshes])
        self.rays = RayMeshIntersector(self.mesh)
        self.patches = patches
        self.radiance = np.asarray(radiance, dtype=float)
        self.ground_albedo = np.asarray(ground_albedo, dtype=float)
        self.rng = rng
        self.areas = np.array([spherical_area(t) for t in patches])
        # Open ground is lit by the whole unoccluded sky: E_up = sum_i r_i int cos.
        self.e_up = self._direct(np.zeros((1, 3)) + [0, 1e6, 0], np.array([[0, 1.0, 0]]), 256)[0]

    def _direct(self, points, normals, per_patch):
        """Direct irradiance (m, 3) at points: uniform samples in each patch, cos-weighted."""
        total = np.zeros((len(points), 3))
        for i, tri in enumerate(self.patches):
            xi = self.rng.random((per_patch, 2))
            dirs = arvo_sample(tri, xi)  # (s, 3)
            cos = np.maximum(normals @ dirs.T, 0.0)  # (m, s)
            pi, si = np.nonzero(cos > 0)
            if len(pi) == 0:
                continue
            blocked = self.rays.intersects_any(points[pi] + OFFSET_M * normals[pi], dirs[si])
            vis = np.zeros_like(cos)
            vis[pi, si] = cos[pi, si] * ~blocked
            total += (self.areas[i] * vis.mean(axis=1))[:, None] * self.radiance[i]
        return total

    def irradiance(
        self, point, normal, direct_per_patch=2000, bounce_rays=4000, bounce_per_patch=24
    ):
        point = np.asarray(point, dtype=float)[None]
        normal = np.asarray(normal, dtype=float)[None]
        direct = self._direct(point, normal, direct_per_patch)[0]
        # Cosine-weighted gather for the one bounce.
        xi = self.rng.random((bounce_rays, 2))
        r, phi = np.sqrt(xi[:, 0]), 2 * np.pi * xi[:, 1]
        n = normal[0]
        helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        dirs = (
            (r * np.cos(phi))[:, None] * t1
            + (r * np.sin(phi))[:, None] * t2
            + np.sqrt(1 - xi[:, 0])[:, None] * n
        )
        origins = np.repeat(point + OFFSET_M * normal, bounce_rays, axis=0)
        tri, ray, loc = self.rays.intersects_id(
            origins, dirs, multiple_hits=False, return_locations=True
        )
        radiance = np.zeros((bounce_rays, 3))
        if len(tri):
            face_n = self.mesh.face_normals[tri]
            front = np.einsum("ij,ij->i", face_n, dirs[ray]) < 0
            tri, ray, loc, face_n = tri[front], ray[front], loc[front], face_n[front]
            e = self._direct(loc, face_n, bounce_per_patch)
            radiance[ray] = self.albedo[tri] / np.pi * e
        # Rays that leave all geometry downward see the open ground beyond it.
        down = (dirs[:, 1] < 0) & (self.rays.intersects_first(origins, dirs) < 0)
        radiance[down] = self.ground_albedo / np.pi * self.e_up
        indirect = np.pi * radiance.mean(axis=0)
        return direct + indirect

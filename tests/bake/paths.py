"""An independent reference with any number of bounces: Monte Carlo paths through trimesh's
ray queries (its Embree intersector), under a uniform sky.

It shares nothing with ``bake.irradiance``: no bounce cache, no sky patches, no sparse
gather. A path leaves the receiver point in a cosine-weighted direction; where it hits a
front face it is multiplied by that face's albedo and goes on in a new cosine-weighted
direction from there; where it escapes upward it sees the sky (radiance ``L``); where it
escapes downward it meets the open ground beyond the modelled one, which reflects the whole
unoccluded sky (radiance ``albedo_ground L``: one more bounce). A back face ends the path.
With cosine-weighted directions the irradiance is ``pi`` times the mean radiance a path
brings back, so ``E_k`` below is exactly the light reflected ``k`` times (``E_0`` the direct
light). Exact in expectation.
"""

from __future__ import annotations

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

OFFSET_M = 1e-3


def cosine_directions(normals: np.ndarray, rng) -> np.ndarray:
    """One cosine-weighted unit direction (m, 3) about each unit normal (m, 3)."""
    xi = rng.random((len(normals), 2))
    r, phi = np.sqrt(xi[:, 0]), 2.0 * np.pi * xi[:, 1]
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    return (
        (r * np.cos(phi))[:, None] * t1
        + (r * np.sin(phi))[:, None] * t2
        + np.sqrt(1.0 - xi[:, 0])[:, None] * normals
    )


class PathReference:
    """Irradiance by bounce count at points under a uniform sky of radiance ``L``.

    Parameters
    ----------
    meshes : list of (trimesh.Trimesh, grey albedo), all blocking and reflecting geometry
        (the ground rectangle included)
    ground_albedo : grey albedo of the open ground beyond the meshes
    """

    def __init__(self, meshes, ground_albedo: float, L: float = 1.0):
        self.mesh = trimesh.util.concatenate([m for m, _ in meshes])
        self.albedo = np.concatenate([np.full(len(m.faces), a, float) for m, a in meshes])
        self.rays = RayMeshIntersector(self.mesh)
        self.ground_albedo = float(ground_albedo)
        self.L = float(L)

    def by_bounces(self, point, normal, paths: int, max_bounces: int, rng) -> np.ndarray:
        """``E_k`` (max_bounces + 1,): the irradiance at ``point`` (3,) with unit ``normal``
        (3,) of light reflected exactly ``k`` times; ``E.sum()`` is the total."""
        E = np.zeros(max_bounces + 2)
        origins = np.repeat(np.asarray(point, float)[None] , paths, axis=0)
        normals = np.repeat(np.asarray(normal, float)[None], paths, axis=0)
        throughput = np.ones(paths)
        alive = np.arange(paths)
        for depth in range(max_bounces + 1):
            dirs = cosine_directions(normals, rng)
            starts = origins + OFFSET_M * normals
            tri, ray, loc = self.rays.intersects_id(
                starts, dirs, multiple_hits=False, return_locations=True
            )
            hit = np.zeros(len(alive), bool)
            hit[ray] = True
            up = ~hit & (dirs[:, 1] > 0.0)
            down = ~hit & (dirs[:, 1] <= 0.0)
            E[depth] += self.L * throughput[up].sum()
            E[depth + 1] += self.ground_albedo * self.L * throughput[down].sum()
            face_n = self.mesh.face_normals[tri]
            front = np.einsum("ij,ij->i", face_n, dirs[ray]) < 0.0
            tri, ray, loc, face_n = tri[front], ray[front], loc[front], face_n[front]
            throughput = throughput[ray] * self.albedo[tri]
            origins, normals, alive = loc, face_n, alive[ray]
            if len(alive) == 0:
                break
        E = np.pi * E / paths
        return E[: max_bounces + 1]

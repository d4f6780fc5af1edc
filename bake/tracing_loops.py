"""The estimator's per-ray loops, compiled with Numba.

Embree traces rays fast (about 19 M occlusion rays/s per core on the demo); what surrounds it
was numpy bookkeeping over arrays of one entry per ray: picking each sample's direction and
weight from its patch's pool, repeating origins, summing the visible weight of each
(point, patch) pair, and the k-d tree that found a bounce hit's cache point. A profile of the
400-light final bake (py-spy, both workers) put 39 s of 122 worker-seconds in the direct
light's numpy bookkeeping and 12 s in the k-d tree, against 41 s in Embree itself. Each loop
here does one pass over its rays without temporaries.

Every function is deterministic: the random numbers are drawn by the caller.
"""

from __future__ import annotations

import numba
import numpy as np

# Compiled code is cached next to this file (``__pycache__``): workers of later bakes load it
# instead of compiling again (all four: 2.2 s to compile in a fresh checkout, 0.7 s to import
# Numba and load them).
_jit = numba.njit(cache=True, nogil=True, fastmath=False)


@_jit
def direct_sample_rays(origins, normals, pair_point, pair_patch, start, pool_dirs, pool_weight,
                       per_pair, ray_origins, ray_dirs, weight):
    """Fill in the visibility rays of (point, patch) pairs, ``per_pair`` per pair, consecutive.

    Pair ``p`` takes entries ``(start[p] + m * (pool // per_pair)) % pool`` of its patch's
    direction pool (a randomly shifted rank-1 lattice over the patch), ``m < per_pair``.

    The outputs are allocated by the caller: numpy re-uses freed memory, arrays allocated here
    were fresh pages every chunk, whose first touch took longer than the loop itself.

    Parameters
    ----------
    origins : (T, 3) float32, ray origins of the points (already off their surface)
    normals : (T, 3) float32, unit
    pair_point, pair_patch : (P,) int, the point and the patch of each pair
    start : (P,) int in [0, pool), first pool entry of each pair
    pool_dirs : (n, pool, 3) float32, unit directions over each patch
    pool_weight : (n, pool) float32, their solid-angle weights (sr)
    per_pair : int, at least 1
    ray_origins, ray_dirs : (P * per_pair, 3) float32, out
    weight : (P * per_pair,) float32, out: solid angle times the clamped cosine to the normal
    """
    pool = pool_dirs.shape[1]
    step = pool // per_pair
    for p in range(len(pair_point)):
        t, i = pair_point[p], pair_patch[p]
        ox, oy, oz = origins[t, 0], origins[t, 1], origins[t, 2]
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        k = start[p]
        for m in range(per_pair):
            r = p * per_pair + m
            dx, dy, dz = pool_dirs[i, k, 0], pool_dirs[i, k, 1], pool_dirs[i, k, 2]
            ray_dirs[r, 0], ray_dirs[r, 1], ray_dirs[r, 2] = dx, dy, dz
            ray_origins[r, 0], ray_origins[r, 1], ray_origins[r, 2] = ox, oy, oz
            weight[r] = pool_weight[i, k] * max(dx * nx + dy * ny + dz * nz, np.float32(0.0))
            k += step  # (start + m * step) % pool, without a division per ray
            if k >= pool:
                k -= pool


@_jit
def scatter_visible(blocked, weight, per_pair, pair_point, pair_patch, unoccluded, out):
    """``out[t, i] = unoccluded[t, i] * visible fraction`` of each pair's rays.

    The fraction is the weight of the pair's unblocked rays over its total weight. Where the
    total is 0 (every sample at or below the surface's horizon: a patch straddling a wall's
    horizon), the share of its rays that are unblocked: the rule before, 1, let a point
    inside a solid read that patch's exact value (about 0.001) and pass for lit in the
    bounce cache (tests/bake/test_contact_fill.py).

    Parameters
    ----------
    blocked : (P * per_pair,) bool, per ray, in :func:`direct_sample_rays` order
    weight : (P * per_pair,) float32
    unoccluded : (T, n) float64, exact unoccluded irradiance per point and patch
    out : (T, n) float32, written at the pairs' entries only
    """
    for p in range(len(pair_point)):
        total = 0.0
        visible = 0.0
        free = 0
        for m in range(per_pair):
            r = p * per_pair + m
            total += weight[r]
            if not blocked[r]:
                visible += weight[r]
                free += 1
        fraction = visible / total if total > 0.0 else free / per_pair
        t, i = pair_point[p], pair_patch[p]
        out[t, i] = unoccluded[t, i] * fraction


@_jit
def cosine_weighted_rays(points, normals, lattice, shift, offset_m, origins, dirs):
    """Fill in cosine-weighted rays around each normal, ``len(lattice)`` per point (the
    bounce's gather rays; the probes that find hull planes buried in other objects).

    Malley's method on the lattice shifted per point (Cranley-Patterson rotation): a uniform
    point ``(u, v)`` of the unit disc's square, lifted to the hemisphere. Tangent frames after
    Duff et al. 2017 (branchless, continuous except at n_z = 0's sign switch).

    Parameters
    ----------
    points, normals : (T, 3) float64
    lattice : (K, 2) float64 in [0, 1)
    shift : (T, 2) float64 in [0, 1)
    offset_m : float, how far off the surface the rays start
    origins, dirs : (T * K, 3) float32, out, grouped by point
    """
    T, K = points.shape[0], lattice.shape[0]
    for t in range(T):
        x, y, z = normals[t, 0], normals[t, 1], normals[t, 2]
        sign = 1.0 if z >= 0.0 else -1.0
        a = -1.0 / (sign + z)
        b = x * y * a
        t1 = (1.0 + sign * x * x * a, sign * b, -sign * x)
        t2 = (b, sign + y * y * a, -y)
        for s in range(K):
            u = (lattice[s, 0] + shift[t, 0]) % 1.0
            v = (lattice[s, 1] + shift[t, 1]) % 1.0
            r = np.sqrt(u)
            phi = 2.0 * np.pi * v
            lx, ly, lz = r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u)
            row = t * K + s
            for j in range(3):
                dirs[row, j] = lx * t1[j] + ly * t2[j] + lz * normals[t, j]
                origins[row, j] = points[t, j] + offset_m * normals[t, j]


@_jit
def raster_lookup(points, faces, face_origin, face_u, face_v, face_cell_m, face_columns,
                  face_rows, face_first, table):
    """The entry of ``table`` under each point in its face's raster (-1: the face has none).

    Each face has a raster in its own plane: cell ``(row, column)`` holds
    ``table[face_first + row * columns + column]``; points outside it take the nearest
    border cell.

    Parameters
    ----------
    points : (m, 3) float64, on their faces
    faces : (m,) int, global face index
    face_origin, face_u, face_v : (F, 3) float64, the raster's corner and unit axes
    face_cell_m : (F,) float64
    face_columns, face_rows, face_first : (F,) int64 (``face_first`` -1: no raster)
    table : (cells,) int64
    """
    out = np.empty(len(points), np.int64)
    for h in range(len(points)):
        f = faces[h]
        if face_first[f] < 0:
            out[h] = -1
            continue
        du = 0.0
        dv = 0.0
        for j in range(3):
            d = points[h, j] - face_origin[f, j]
            du += d * face_u[f, j]
            dv += d * face_v[f, j]
        column = min(max(int(np.floor(du / face_cell_m[f])), 0), face_columns[f] - 1)
        row = min(max(int(np.floor(dv / face_cell_m[f])), 0), face_rows[f] - 1)
        out[h] = table[face_first[f] + row * face_columns[f] + column]
    return out

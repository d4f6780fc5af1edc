"""Basis irradiance: what each sky patch, at unit radiance, delivers to a receiver point.

Renderer choice
---------------
A small purpose-built estimator on Embree (``embreex``) rather than Mitsuba 3. What we need is
irradiance at many scattered points (texels of several atlases, pixels of fixed views) for
hundreds of separate lights, twice (with and without the virtual objects). A path tracer
renders one light configuration per image; here one batch of visibility rays serves every light
and both configurations at once, and the light-independent parts are exact:

- **Direct light** from patch ``i`` at a point with normal ``n`` is
  ``E_i = integral over patch i of V(w) max(0, n.w) dw``. The unoccluded integral is computed
  exactly with Lambert's polygon formula (the patch clipped to the surface's hemisphere), and
  multiplied by the cosine-weighted visible fraction estimated from ``samples_per_patch`` rays
  spread over the patch (stratified lattice with a random shift per point and patch). So soft
  shadows come from sampling the whole patch, and an unoccluded point is *exact*: pi*L under a
  uniform sky, pi*L/2 on a wall.
- **One bounce** (colour bleeding between real proxies and virtual objects, Sato Fig. 7):
  direct irradiance is first computed at a *bounce cache* of points spread over every surface.
  A receiver point then casts ``bounce_rays`` cosine-weighted rays; a ray that hits a surface
  picks up ``albedo * E_cache / bounce_rays`` from the nearest cache point on the same face, a
  ray that escapes downward meets the infinite ground beyond the modelled extent, lit by the
  open sky. Summing over all lights is one sparse matrix product.
- **More bounces** (``[quality] bounces = N``): before the receivers gather, the cache points
  gather from each other the same way (:func:`cache_bounces`): one sparse (C, C) gather
  matrix ``G`` per configuration, traced once, and ``B_k = G (albedo (E + B_(k-1)))`` plus
  the open ground's share, ``N - 1`` times. A receiver's gather then reads
  ``albedo (E + B_(N-1))``, so its bounce holds light reflected 1 to N times (inside a closed
  box lit with ``E`` everywhere: ``E (rho + ... + rho^N)``).

Light configurations
--------------------
``"all"``: virtual objects, real proxies and ground block light (``I``, ``O``).
``"real"``: only the real proxies and ground (``d`` of ground/wall planes, ``S``).
``"none"``: nothing but the infinite ground (``d`` of hull planes: the unshadowed shading the
client applies to virtual objects in hull-plane mode).

Every function is deterministic for a given ``numpy.random.Generator`` state.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from bake import tracing_loops as loops
from bake.cachepoints import lattice, nearest_point_rasters
from bake.raytrace import RAY_OFFSET_M, Geometry, RayScene
from bake.rowstore import RowFile
from daylit.spherical import clipped_cosine_integral, sample_triangles

CONFIGS = ("all", "real", "none")
POOL_FACTOR = 64  # directions per patch in the pool, per sample drawn


@dataclass
class SceneSet:
    """The ray scenes of each light configuration plus the one geometry they index into.

    ``face_ids[config]`` maps a face of that configuration's scene to the global face index.
    """

    geometry: Geometry
    scenes: dict
    face_ids: dict
    ground_albedo: np.ndarray

    @classmethod
    def build(cls, geometry: Geometry, ground_albedo: np.ndarray) -> SceneSet:
        everything = np.arange(len(geometry.faces))
        real = np.flatnonzero(~geometry.virtual)
        return cls(
            geometry=geometry,
            scenes={
                "all": RayScene(geometry),
                "real": RayScene(geometry.subset(~geometry.virtual)),
                "none": RayScene(geometry.subset(np.zeros(len(geometry.faces), bool))),
            },
            face_ids={"all": everything, "real": real, "none": np.zeros(0, np.int64)},
            ground_albedo=np.asarray(ground_albedo, dtype=np.float64),
        )


@dataclass
class BounceCache:
    """Points on every surface with their direct basis irradiance.

    Attributes
    ----------
    points : (C, 3) float, metres, on the surfaces
    normals : (C, 3) float, the face normals
    faces : (C,) int, global face index of each point
    albedo : (C, 3) float
    E : dict config -> (C, n) float32, direct irradiance at unit patch radiance
    geometry : Geometry, the faces ``faces`` index
    cell_m : float, raster cell of the nearest-point look-up (half the cache spacing)
    bounce : dict config -> (C, n, 3) float32 or None: the cache points' own indirect
        irradiance (bounces 1 to N - 1, :func:`cache_bounces`); None for one bounce
    lit : (C,) bool or None: the points some light reaches with everything present (from
        ``E["all"]`` when None)
    picked : dict config -> (C, n * 3) float32 or None: what a gather ray picks up
        (:func:`picked_up`, from ``E`` and ``bounce`` when None); the local pool's workers
        get it memory-mapped from the files :func:`write_shared_cache` wrote, one copy in
        the page cache for them all, rather than each making its own
    """

    points: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray
    E: dict
    geometry: Geometry
    cell_m: float
    bounce: dict | None = None
    lit: np.ndarray | None = None
    picked: dict | None = None

    def __post_init__(self):
        # Points no light reaches with everything present are buried (the ground under a
        # wall): a hit beside the wall's foot must not read one of them as its nearest, or
        # the ground's bounce there reads dark (a test bake's ground 5 cm from a wall: 15 %
        # low on the side whose jittered cache points fell under the wall).
        lit = lit_points(self.E, len(self.points)) if self.lit is None else self.lit
        keep = np.flatnonzero(lit)
        raster = nearest_point_rasters(
            self.geometry, self.points[keep], self.faces[keep], self.cell_m
        )
        self._raster = raster[:-1] + (keep[raster[-1]],)
        # Albedo times irradiance, flattened to (C, n * 3): what one bounce ray picks up,
        # made on first use (the bake process's own cache, which only gathers the cache's
        # bounces, never makes it: two of them were 1.9 GB of the palace's cache stage at
        # 160 lights). float32, as the gather matrix: the gather streams this whole array
        # once per chunk, and float64 doubled its time (results differ by 1e-6 relative).
        # Multiplied in float32 too: a float64 product slowed every worker's start (page
        # faults of its size). Figures: docs/benchmarks.md, "Figures behind choices in the code".
        self._picked_up = dict(self.picked) if self.picked is not None else {}

    @classmethod
    def from_arrays(cls, arrays, geometry: Geometry) -> BounceCache:
        """The cache from the arrays ``cache.npz`` holds (an open ``np.load`` file or a dict
        of them: ``points``, ``normals``, ``faces``, ``albedo``, ``E_all``, ``E_real``,
        ``cell_m``, and ``B_all``, ``B_real`` when there is more than one bounce); the local
        pool's workers and a cluster's both build theirs here."""
        names = set(getattr(arrays, "files", arrays))
        return cls(
            arrays["points"],
            arrays["normals"],
            arrays["faces"],
            arrays["albedo"],
            {"all": arrays["E_all"], "real": arrays["E_real"]},
            geometry,
            float(arrays["cell_m"]),
            {"all": arrays["B_all"], "real": arrays["B_real"]} if "B_all" in names else None,
        )

    @classmethod
    def from_files(cls, cache_file, geometry: Geometry) -> BounceCache:
        """The cache of ``cache_file`` (``cache.npz``) with what :func:`write_shared_cache`
        wrote beside it memory-mapped, read-only (the irradiance itself is not loaded); a
        cache written without them (a partial bake from before 2026-12-04) as
        :meth:`from_arrays`."""
        shared = shared_cache_files(cache_file)
        with np.load(cache_file) as data:
            if not all(path.is_file() for path in shared.values()):
                return cls.from_arrays(data, geometry)
            small = {k: data[k] for k in ("points", "normals", "faces", "albedo", "cell_m")}
        maps = {k: np.load(path, mmap_mode="r") for k, path in shared.items()}
        return cls(small["points"], small["normals"], small["faces"], small["albedo"], {},
                   geometry, float(small["cell_m"]), None, lit=np.asarray(maps.pop("lit")),
                   picked=maps)

    def nearest(self, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """The cache point nearest to each point on its face (to within half a raster cell),
        shape ``(m,)`` int; -1 where the face has no cache point (a sliver of ground)."""
        return loops.raster_lookup(
            np.ascontiguousarray(points, dtype=np.float64),
            np.ascontiguousarray(faces, dtype=np.int64),
            *self._raster,
        )

    def picked_up(self, config: str) -> np.ndarray:
        if config not in self._picked_up:
            self._picked_up[config] = picked_up(
                self.E[config], self.albedo, (self.bounce or {}).get(config)
            )
        return self._picked_up[config]


def lit_points(E: dict, count: int) -> np.ndarray:
    """(count,) bool: the cache points some light reaches with everything present (all of
    them where none is, or without ``E["all"]``)."""
    lit = np.ones(count, bool)
    if "all" in E and count:
        lit = np.asarray(E["all"]).max(axis=1) > 0.0
        if not lit.any():
            lit[:] = True
    return lit


def shared_cache_files(cache_file) -> dict:
    """The files :func:`write_shared_cache` writes beside ``cache_file``: ``{"lit": path,
    config: path}`` for the configurations ``all`` and ``real``."""
    folder, stem = cache_file.parent, cache_file.name.split(".")[0]
    return {"lit": folder / f"{stem}-lit.npy",
            **{config: folder / f"{stem}-picked-{config}.npy" for config in ("all", "real")}}


def write_shared_cache(cache_file, E: dict, albedo: np.ndarray, bounce: dict | None,
                       rows: int = 65536) -> None:
    """Write beside ``cache_file`` what the workers' gathers read (:meth:`BounceCache.from_files`):
    the lit points and, for ``E``'s configurations ``all`` and ``real`` ((C, n) float32 each,
    ``bounce`` (C, n, 3) or None), :func:`picked_up` as (C, n * 3) float32 ``.npy`` files,
    made ``rows`` cache points at a time (each a temporary name first, then renamed)."""
    paths = shared_cache_files(cache_file)
    lit = lit_points(E, len(albedo))
    tmp = paths["lit"].with_name(paths["lit"].name + ".tmp")
    with open(tmp, "wb") as f:
        np.save(f, lit)
    os.replace(tmp, paths["lit"])
    for config in ("all", "real"):
        C, n = E[config].shape
        tmp = paths[config].with_name(paths[config].name + ".tmp")
        out = RowFile.create(tmp, (C, n * 3))  # written by rows with plain file I/O
        for a in range(0, C, rows):
            b = min(C, a + rows)
            out.write(a, picked_up(E[config][a:b], albedo[a:b],
                                   None if bounce is None else bounce[config][a:b]))
        os.replace(tmp, paths[config])


def picked_up(E: np.ndarray, albedo: np.ndarray, bounce: np.ndarray | None) -> np.ndarray:
    """What a gather ray that hits a cache point picks up: ``albedo (E + bounce)``,
    (C, n * 3) float32, from direct ``E`` (C, n), ``albedo`` (C, 3) and the point's own
    indirect irradiance ``bounce`` (C, n, 3) or None."""
    total = E.astype(np.float32)[:, :, None]
    if bounce is not None:
        total = total + bounce.astype(np.float32)
    return (total * albedo.astype(np.float32)[:, None, :]).reshape(len(E), -1)


def cache_bounces(estimator: Estimator, bounces: int, rng, batch: int = 20_000,
                  light_block_bytes: int = 256 << 20, out=None) -> dict | None:
    """The cache points' own indirect irradiance after ``bounces - 1`` bounces, for every
    configuration of ``estimator.cache.E``: ``{config: (C, n, 3) float32}``; None when
    ``bounces <= 1`` (the receivers' gather is then the one bounce).

    Each cache point casts ``estimator.bounce_rays`` gather rays once (one sparse (C, C)
    matrix per configuration, :meth:`Estimator.gather`); then ``B_k = G (albedo (E +
    B_(k-1))) + (open ground's share)``, ``B_0 = 0``, for blocks of lights of at most
    ``light_block_bytes`` of float64 per product. Deterministic for a given ``rng``.
    ``out(config, shape)`` gives each configuration's array to fill (default: in memory; the
    bake gives a memory-mapped file, so that C x n x 3 is never held at once).
    """
    cache = estimator.cache
    if bounces <= 1 or cache is None or estimator.bounce_rays == 0:
        return None
    C, n = len(cache.points), estimator.n
    ground = (estimator.up_irradiance[:, None] * estimator.scenes.ground_albedo[None, :])
    ground = ground.reshape(1, -1).astype(np.float32)  # (1, n * 3)
    make = out or (lambda config, shape: np.empty(shape, np.float32))
    result = {}
    for config, E in cache.E.items():
        rows, downs = [], []
        for start in range(0, C, batch):
            stop = min(start + batch, C)
            gather, down = estimator.gather(
                cache.points[start:stop], cache.normals[start:stop], config, rng
            )
            rows.append(gather)
            downs.append(down)
        G = scipy.sparse.vstack(rows, format="csr")
        G.sum_duplicates()
        down = np.concatenate(downs).astype(np.float32)[:, None]  # (C, 1)
        # By blocks of lights (each light's bounces are its own; the same bits as all at
        # once): the products' temporaries stay within `light_block_bytes`, not C x n x 3
        # several times over (7.8 GB in the palace's cache stage at 160 lights).
        result[config] = make(config, (C, n, 3))
        step = max(1, light_block_bytes // max(1, C * 3 * 8))
        for a in range(0, n, step):
            b = min(n, a + step)
            B = None
            for _ in range(bounces - 1):
                B = (G @ picked_up(E[:, a:b], cache.albedo, B)
                     + down * ground[:, 3 * a : 3 * b]).reshape(C, b - a, 3)
            result[config][:, a:b] = B
    return result


class Estimator:
    """Computes basis irradiance at points for the lights of one dome.

    Parameters
    ----------
    dome_vertices : (n, 3, 3) float
    scenes : SceneSet
    samples_per_patch : int
        Visibility rays per point and light.
    bounce_rays : int
        Gather rays per point for the indirect bounce (0: direct light only).
    cache : BounceCache or None
        Needed when ``bounce_rays > 0``.
    """

    def __init__(
        self,
        dome_vertices,
        scenes: SceneSet,
        samples_per_patch: int,
        bounce_rays: int,
        cache: BounceCache | None = None,
    ):
        self.tris = np.asarray(dome_vertices, dtype=np.float64)
        self.n = self.tris.shape[0]
        self.scenes = scenes
        self.samples_per_patch = samples_per_patch
        self.bounce_rays = bounce_rays
        self.cache = cache
        self.up_irradiance = clipped_cosine_integral(self.tris, np.array([[0.0, 1.0, 0.0]]))[0]
        # Direction pool per patch: a Fibonacci lattice of POOL_FACTOR * M points over the
        # patch, with solid-angle weights (float32: this is the hot loop's data).
        pool = POOL_FACTOR * samples_per_patch
        uv = np.broadcast_to(lattice(pool)[:, None, :], (pool, self.n, 2))
        dirs, weight = sample_triangles(self.tris, uv)  # (pool, n, 3), (pool, n)
        self._pool_dirs = np.ascontiguousarray(dirs.transpose(1, 0, 2), dtype=np.float32)
        self._pool_weight = np.ascontiguousarray(weight.T, dtype=np.float32)
        self._hemisphere_lattice = lattice(max(bounce_rays, 1))
        self._exact_cache: dict[bytes, np.ndarray] = {}
        self._scratch: dict[str, np.ndarray] = {}
        self.rays_cast = 0  # since the last chunk began (:meth:`chunk`)

    def _buffer(self, name: str, shape: tuple, dtype) -> np.ndarray:
        """A scratch array re-used from chunk to chunk (its contents are overwritten). Ray
        arrays are tens of MB; allocated anew for every chunk they were fresh pages, whose
        first touch cost more than filling them (1.8 M direct rays: 19.7 ms against 8.5 ms)."""
        size = int(np.prod(shape))
        held = self._scratch.get(name)
        if held is None or held.dtype != dtype or held.size < size:
            held = self._scratch[name] = np.empty(size, dtype=dtype)
        return held[:size].reshape(shape)

    # ---------------------------------------------------------------------------------------
    def exact_unoccluded(self, normals: np.ndarray) -> np.ndarray:
        """Lambert's exact unoccluded irradiance ``(T, n)``, computed once per distinct normal
        (plane receivers share one normal; lightmap texels share their face's)."""
        key = np.ascontiguousarray(np.round(np.asarray(normals, dtype=np.float64), 9))
        rows = key.view(np.dtype((np.void, key.dtype.itemsize * 3))).ravel()
        unique_rows, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
        missing = [j for j, r in enumerate(unique_rows) if r.tobytes() not in self._exact_cache]
        if missing:
            values = clipped_cosine_integral(self.tris, key[first[missing]])
            for j, row in zip(missing, values, strict=True):
                self._exact_cache[unique_rows[j].tobytes()] = row
        table = np.stack([self._exact_cache[r.tobytes()] for r in unique_rows])
        return table[inverse.ravel()]

    def direct(self, points, normals, configs, rng) -> dict:
        """Direct irradiance from each patch: ``{config: (T, n) float32}``.

        ``configs`` is any of ``"all"``, ``"real"``, ``"none"``; one set of rays serves all.
        Each (point, patch) pair traces ``samples_per_patch`` directions: every
        ``POOL_FACTOR``-th entry of the patch's direction pool from a random start, i.e. a
        randomly shifted rank-1 lattice over the patch (stratified, independent per pair).
        """
        points = np.asarray(points, dtype=np.float64)
        normals = np.asarray(normals, dtype=np.float64)
        exact = self.exact_unoccluded(normals)  # (T, n)
        out = {}
        if "none" in configs:
            out["none"] = exact.astype(np.float32)
        traced = [c for c in configs if c != "none"]
        if not traced:
            return out
        M, pool = self.samples_per_patch, self._pool_dirs.shape[1]
        t_idx, i_idx = np.nonzero(exact > 0.0)  # pairs that can receive anything
        start = rng.integers(0, pool, size=len(t_idx))
        # Every sample is traced, also the few below the surface's horizon (weight 0): cheaper
        # than compressing the arrays, and their result is multiplied by 0.
        origins32 = (points + RAY_OFFSET_M * normals).astype(np.float32)
        origins = self._buffer("origins", (len(t_idx) * M, 3), np.float32)
        ray_dirs = self._buffer("dirs", (len(t_idx) * M, 3), np.float32)
        w = self._buffer("weight", (len(t_idx) * M,), np.float32)
        loops.direct_sample_rays(
            origins32, normals.astype(np.float32), t_idx, i_idx, start,
            self._pool_dirs, self._pool_weight, M, origins, ray_dirs, w,
        )
        blocked = {"all": self.scenes.scenes["all"].occluded(origins, ray_dirs)}
        rays = len(origins)
        if "real" in traced:
            # The real scene is a subset of everything: only rays blocked there can be blocked.
            real_blocked = np.zeros_like(blocked["all"])
            maybe = np.flatnonzero(blocked["all"])
            real_blocked[maybe] = self.scenes.scenes["real"].occluded(
                origins[maybe], ray_dirs[maybe]
            )
            blocked["real"] = real_blocked
            rays += len(maybe)
        for config in traced:
            E = np.zeros(exact.shape, dtype=np.float32)
            loops.scatter_visible(blocked[config], w, M, t_idx, i_idx, exact, E)
            out[config] = E
        self.rays_cast += rays
        return out

    # ---------------------------------------------------------------------------------------
    def bounce(self, points, normals, config: str, rng) -> np.ndarray:
        """Irradiance after the diffuse bounces, ``(T, n, 3)`` float32 (RGB from albedos):
        one, or more when the cache carries its own bounce (:func:`cache_bounces`)."""
        T = len(points)
        if self.bounce_rays == 0 or T == 0:
            return np.zeros((T, self.n, 3), dtype=np.float32)
        gather, down = self.gather(points, normals, config, rng)
        out = np.asarray(gather @ self.cache.picked_up(config), dtype=np.float32)
        # Rays that leave the modelled geometry downward meet the open ground beyond it.
        if np.any(down):
            ground = self.up_irradiance[:, None] * self.scenes.ground_albedo[None, :]  # (n, 3)
            out += (down[:, None] * ground.reshape(1, -1)).astype(np.float32)
        return out.reshape(T, self.n, 3)

    def gather(self, points, normals, config: str, rng):
        """Cast ``bounce_rays`` cosine-weighted rays from each point (T, 3) into the
        configuration's scene and return what they hit: ``gather`` (T, C) sparse CSR float32,
        ``1 / K`` per ray at the cache point nearest its hit (none for back faces and faces
        without cache points), and ``down`` (T,) float64, the fraction of rays that escape
        downward (they meet the open ground beyond the modelled extent)."""
        T, K = len(points), self.bounce_rays
        # Cosine-weighted directions around each normal: Malley's method on a shifted lattice.
        origins = self._buffer("bounce origins", (T * K, 3), np.float32)
        dirs = self._buffer("bounce dirs", (T * K, 3), np.float32)
        loops.cosine_weighted_rays(
            np.ascontiguousarray(points, dtype=np.float64),
            np.ascontiguousarray(normals, dtype=np.float64),
            self._hemisphere_lattice,
            rng.random((T, 2)),
            RAY_OFFSET_M,
            origins,
            dirs,
        )
        owner = np.repeat(np.arange(T), K)
        scene = self.scenes.scenes[config]
        face, distance = scene.first_hit(origins, dirs)
        self.rays_cast += len(origins)
        hit = face >= 0
        C = len(self.cache.points)
        if np.any(hit):
            global_face = self.scenes.face_ids[config][face[hit]]
            hit_points = origins[hit] + distance[hit, None] * dirs[hit]
            index = self.cache.nearest(hit_points, global_face)
            # Back faces (inside closed objects) reflect nothing, nor faces without cache points.
            facing = (
                np.einsum("ij,ij->i", dirs[hit], self.scenes.geometry.face_normals[global_face])
                < 0.0
            )
            weight = np.where(facing & (index >= 0), np.float32(1.0 / K), np.float32(0.0))
            # Rows are already in order (rays are grouped by point): build the CSR matrix
            # directly, without the sort a (row, column) construction does.
            gather = scipy.sparse.csr_matrix(
                (
                    weight,
                    np.maximum(index, 0),
                    np.concatenate([[0], np.cumsum(np.bincount(owner[hit], minlength=T))]),
                ),
                shape=(T, C),
            )
        else:
            gather = scipy.sparse.csr_matrix((T, C), dtype=np.float32)
        down = ~hit & (dirs[:, 1] < 0.0)
        return gather, np.bincount(owner[down], minlength=T) / K

    # ---------------------------------------------------------------------------------------
    def basis(self, points, normals, configs, rng) -> dict:
        """Direct light and the traced bounce, kept apart so the noisy bounce can be
        smoothed before the two are added: ``{config: (T, n), "bounce:" + config:
        (T, n, 3)}`` float32 for traced configurations. Their direct light is grey (the same
        for R, G and B), so it is kept as one value per light: a third of the RGB bytes.

        ``"none"`` is ``(T, n, 3)``, its bounce (the open ground's, in closed form) included:
        ``albedo_ground * E_up_i * (1 - n_y) / 2`` (a uniformly lit lower hemisphere).
        """
        direct = self.direct(points, normals, configs, rng)
        out = {}
        for config in configs:
            if config == "none":
                lower = 0.5 * (1.0 - np.asarray(normals)[:, 1])  # (T,)
                out[config] = direct[config][:, :, None] + (
                    lower[:, None, None]
                    * self.up_irradiance[None, :, None]
                    * self.scenes.ground_albedo[None, None, :]
                ).astype(np.float32)
                continue
            out[config] = direct[config]
            if self.bounce_rays > 0:
                out["bounce:" + config] = self.bounce(points, normals, config, rng)
        return out

    def chunk(self, points, normals, configs, bounce: bool, seed_words) -> tuple[dict, int]:
        """One chunk of points, as the local pool and a cluster's workers both run it (one
        code path, seeded per chunk: their builds are bit-identical): ``{config: array}``
        (:meth:`basis` with the bounce, else :meth:`direct`) and the rays cast for it."""
        self.rays_cast = 0
        rng = np.random.default_rng(seed_words)
        run = self.basis if bounce else self.direct
        return run(points, normals, configs, rng), self.rays_cast

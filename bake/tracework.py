"""The points a bake traces and their tracing: the bounce cache's points, every atlas texel
and view hit, split into chunks (whose layout does not depend on the worker count), traced in
a process pool of Embree workers (or on a Dask cluster: bake.cluster) and saved as chunk files
under the partial folder, so an interrupted bake resumes from its finished chunks. Each
chunk's random numbers come from ``(seed, stage, name, chunk)``: results are identical for a
seed however many workers ran, and wherever.
"""

from __future__ import annotations

import concurrent.futures as futures
import multiprocessing
import os
import signal
import sys
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bake import chunkio, contact
from bake.cachepoints import cache_points
from bake.irradiance import (
    BounceCache,
    Estimator,
    SceneSet,
    cache_bounces,
    write_shared_cache,
)
from bake.raytrace import RayScene

RAYS_PER_CHUNK = 3_000_000
STAGE_CODES = {"cache": 1, "atlas": 2, "view": 3, "cache bounces": 4}


@dataclass
class PointSet:
    """Points that need basis values: an atlas's texels or a view's pixel hits."""

    stage: str
    name: str
    points: np.ndarray
    normals: np.ndarray
    configs: tuple
    bounce: bool = True
    chunks: list = field(default_factory=list)

    def split(self, chunk_size: int) -> None:
        self.chunks = [
            (start, min(start + chunk_size, len(self.points)))
            for start in range(0, len(self.points), chunk_size)
        ]


_WORKER: dict = {}

# Workers start from a clean server process, not forked from this one: this process has run
# Embree (TBB's thread pool), and a fork taken while a TBB thread holds its lock deadlocks the
# child (seen once in the test suite: a worker stuck in tbb::market::adjust_demand, the bake
# waiting for it forever). The server imports this module once, so workers start fast.
_WORKER_CONTEXT = multiprocessing.get_context("forkserver")
_WORKER_CONTEXT.set_forkserver_preload([__name__])


def _init_worker(geometry, dome_vertices, ground_albedo, samples, bounce_rays, cache_file):
    # Ctrl-C reaches the whole process group: the parent decides, workers just finish.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    scenes = SceneSet.build(geometry, ground_albedo)
    cache = None if cache_file is None else BounceCache.from_files(cache_file, geometry)
    _WORKER["estimator"] = Estimator(dome_vertices, scenes, samples, bounce_rays, cache)


def _run_chunk(task):
    """Compute one chunk in a worker and save it to ``path`` (``{config: array}``, written
    under a temporary name, then renamed); returns the rays cast.

    The worker saves, not the baking process: sending the arrays back (gigabytes at 400
    lights: docs/benchmarks.md, "Baking") made the baking process unpickle and write them
    all on its own while the workers took both cores."""
    points, normals, configs, bounce, seed_words, path = task
    estimator: Estimator = _WORKER["estimator"]
    out, rays = estimator.chunk(points, normals, configs, bounce, seed_words)
    chunkio.save_chunk(path, out)
    return rays


class TraceWork:
    """The points to trace (bounce cache, atlas texels, view hits), chunked, and running them."""

    def __init__(self, site, dome, geometry, atlases, view_hits, samples, log):
        self.site, self.dome, self.geometry, self.samples = site, dome, geometry, samples
        settings = site.settings
        rng = np.random.default_rng([settings.seed, 0])
        t0 = time.perf_counter()
        self.cache = cache_points(
            geometry, settings.cache_spacing_m, max(2.0, 3 * settings.cache_spacing_m), rng
        )
        placed = len(self.cache[0])
        # Finer near contact lines, where a hit's nearest lit cache point lies farther out.
        self.cache = contact.refine_cache(
            geometry, RayScene(geometry), *self.cache, settings.cache_spacing_m
        )
        added = len(self.cache[0]) - placed
        # Placing the points is the cache stage's too (the stage report's "cache").
        self.placing_s = time.perf_counter() - t0
        points, normals, _ = self.cache
        self.cache_set = PointSet("cache", "cache", points, normals, ("all", "real"), bounce=False)
        sets = [
            PointSet("atlas", f"{a.id}.{stack}", a.points, a.normals, (config,))
            for a in atlases.values()
            for stack, config in a.stacks.items()
        ]
        for name, hits in view_hits.items():
            for stack, config in (("O", "all"), ("S", "real")):
                sets.append(
                    PointSet(
                        "view",
                        f"{name}.{stack}",
                        hits[stack].points,
                        hits[stack].normals,
                        (config,),
                    )
                )
        self.stack_names = [s.name for s in sets]  # <atlas or view>.<stack>
        # Stacks that share points and differ only in configuration are traced together.
        self.point_sets = _merge_shared(sets)
        chunk = max(64, RAYS_PER_CHUNK // max(1, dome.count * samples))
        for s in [self.cache_set, *self.point_sets]:
            s.split(chunk)
        self.total_points = len(points) + sum(len(s.points) for s in self.point_sets)
        log(
            f"  {len(points)} bounce-cache points ({added} of them along contact lines); "
            f"{self.total_points} points in all; "
            f"{samples} rays per light and point, {settings.bounce_rays} bounce rays"
        )

    def run(self, partial: Path, workers: int, progress: bool, stage_s: dict, log, cluster=None):
        """Trace every missing chunk (cache first: the rest gathers its bounce from it), in a
        pool of ``workers`` processes or on ``cluster`` (a :class:`bake.cluster.Cluster`).
        Returns (rays cast, seconds)."""
        site, geometry = self.site, self.geometry
        bar = tqdm(
            total=self.total_points,
            unit="pt",
            unit_scale=True,
            disable=not progress,
            desc="baking",
            smoothing=0.05,
            file=sys.stderr,
            dynamic_ncols=True,
        )
        init = (
            geometry,
            self.dome.vertices,
            site.ground.albedo,
            self.samples,
            site.settings.bounce_rays,
        )
        seed = site.settings.seed
        rays = 0
        t0 = time.perf_counter()
        try:
            rays += _run_sets([self.cache_set], partial, seed, init, None, workers, bar, cluster)
            cache_file = self._save_cache(partial)
            stage_s["cache"] = time.perf_counter() - t0 + self.placing_s
            t1 = time.perf_counter()
            rays += _run_sets(
                self.point_sets, partial, seed, init, cache_file, workers, bar, cluster
            )
            stage_s["trace"] = time.perf_counter() - t1
        except KeyboardInterrupt:
            bar.close()
            done = len(list((partial / "chunks").glob("*" + chunkio.SUFFIX)))
            log(
                f"interrupted: {done} finished chunks kept in {partial}; run the same command "
                "again to resume"
            )
            raise
        finally:
            bar.close()
        return rays, time.perf_counter() - t0

    def _save_cache(self, partial: Path) -> Path:
        points, normals, faces = self.cache
        E = _load_set(self.cache_set, partial)
        settings = self.site.settings
        cache_file = partial / "cache.npz"
        tmp = cache_file.with_suffix(".tmp.npz")
        arrays = dict(
            points=points,
            normals=normals,
            faces=faces,
            albedo=self.geometry.albedo[faces],
            E_all=E["all"],
            E_real=E["real"],
            cell_m=0.5 * settings.cache_spacing_m,
        )
        # More than one bounce: the cache points' own bounces (bake.irradiance.cache_bounces),
        # into files beside the cache (C x lights x 3 each: 2.4 GB for the palace at 400
        # lights), read from there into cache.npz and the shared files by blocks.
        def bounce_file(config, shape):
            return np.lib.format.open_memmap(
                partial / f"cache-B-{config}.npy", mode="w+", dtype=np.float32, shape=shape
            )

        bounce = cache_bounces(
            Estimator(
                self.dome.vertices,
                SceneSet.build(self.geometry, self.site.ground.albedo),
                1,
                settings.bounce_rays,
                BounceCache(**{k: arrays[k] for k in ("points", "normals", "faces", "albedo")},
                            E={"all": E["all"], "real": E["real"]}, geometry=self.geometry,
                            cell_m=arrays["cell_m"]),
            ),
            settings.bounces,
            np.random.default_rng([settings.seed, STAGE_CODES["cache bounces"]]),
            out=bounce_file,
        )
        if bounce is not None:
            arrays.update(B_all=bounce["all"], B_real=bounce["real"])
        # Before cache.npz, whose presence says the cache is whole.
        write_shared_cache(cache_file, E, arrays["albedo"], bounce)
        np.savez(tmp, **arrays)
        os.replace(tmp, cache_file)
        del bounce, arrays
        for path in partial.glob("cache-B-*.npy"):
            path.unlink()
        return cache_file


def _merge_shared(sets: list[PointSet]) -> list[PointSet]:
    """Join point sets over the same points (e.g. an atlas's I and d) into one traced set."""
    merged: list[PointSet] = []
    for s in sets:
        for m in merged:
            if m.points is s.points and m.bounce == s.bounce:
                m.configs = tuple(dict.fromkeys(m.configs + s.configs))
                m.name = m.name.split(".")[0] + ".shared"
                break
        else:
            merged.append(PointSet(s.stage, s.name, s.points, s.normals, s.configs, s.bounce))
    return merged


class TracedResults:
    """The traced arrays of the point sets, read from their chunk files on demand."""

    def __init__(self, sets: list[PointSet], partial: Path):
        self.sets, self.partial = sets, partial

    def load(self, owner: str, lights: slice | None = None, names=None) -> dict:
        """{set name: arrays} of every set of an atlas or view ``owner`` (``<owner>.*``):
        of the lights ``lights`` only (default all), and of the arrays ``names`` only (a
        configuration and ``bounce:<configuration>``; default all)."""
        return {
            s.name: _load_set(s, self.partial, lights, names)
            for s in self.sets
            if s.name.split(".")[0] == owner
        }


def lookup_result(results: dict, name: str, config: str):
    """(direct, bounce or None) of one stack: its configuration's arrays, direct (P, n) grey
    or (P, n, 3), bounce (P, n, 3) (see :meth:`Estimator.basis`)."""
    found = results[name] if name in results else results[name.split(".")[0] + ".shared"]
    return found[config], found.get("bounce:" + config)


def release_result(results: dict, name: str, config: str) -> None:
    """Drop one stack's configuration arrays (as :func:`lookup_result` finds them) from
    ``results``, so that they are let go of once no stack needs them any more."""
    found = results[name] if name in results else results[name.split(".")[0] + ".shared"]
    found.pop(config, None)
    found.pop("bounce:" + config, None)


def _chunk_path(partial: Path, s: PointSet, index: int) -> Path:
    return partial / "chunks" / f"{s.stage}-{s.name}-{index:05d}{chunkio.SUFFIX}"


def _run_sets(sets, partial, seed, init, cache_file, workers, bar, cluster=None) -> int:
    """Compute every missing chunk of ``sets`` in a process pool of ``workers`` (or on
    ``cluster``) with the bounce cache of ``cache_file`` (``None``: none); returns rays
    cast."""
    todo = []
    for s in sets:
        for index, (start, stop) in enumerate(s.chunks):
            path = _chunk_path(partial, s, index)
            if path.is_file():
                bar.update(stop - start)
                continue
            words = [seed, STAGE_CODES[s.stage], zlib.crc32(s.name.encode()), index]
            task = (s.points[start:stop], s.normals[start:stop], s.configs, s.bounce, words, path)
            todo.append((stop - start, task))
    if not todo:
        return 0
    if cluster is not None:
        cache = None
        if cache_file is not None:
            with np.load(cache_file) as data:
                cache = {name: data[name] for name in data.files}
        return cluster.run(todo, init, cache, bar)
    rays = 0
    with futures.ProcessPoolExecutor(
        max_workers=workers,
        mp_context=_WORKER_CONTEXT,
        initializer=_init_worker,
        initargs=init + (cache_file,),
    ) as pool:
        pending = {pool.submit(_run_chunk, task): count for count, task in todo}
        try:
            for future in futures.as_completed(pending):
                rays += future.result()
                bar.update(pending.pop(future))
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    return rays


def _load_set(s: PointSet, partial: Path, lights=None, names=None) -> dict:
    """Every array the set's chunks hold (configurations and their bounces), concatenated
    (``lights`` and ``names``: :meth:`TracedResults.load`)."""
    paths = [_chunk_path(partial, s, i) for i in range(len(s.chunks))]
    return chunkio.load_chunks(paths, lights, names)

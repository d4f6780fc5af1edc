"""``daylit bake``: from a checked site description to a complete build directory.

Stages (each split into chunks of points whose layout does not depend on the worker count):

1. **cache** — direct basis irradiance at the bounce-cache points (configurations all, real);
2. **receivers** — direct + one bounce at every texel of the hull, ground and lightmap atlases
   and at every pixel hit of the fixed views;
3. **write** — stacks into EXR masters and compact textures (``bake.compress``), masks,
   ``site.glb``, ``manifest.json``. Atlases and views are written two at a time in threads:
   one's single-threaded parts (EXR writing, quantizing, checking) run while the other's
   encoders use the cores.

Chunks run in a process pool (one worker per core; Embree is single-threaded per call here)
and are saved as they finish under ``.<out>.partial/``, keyed by a hash of every input, so an
interrupted bake resumes from its finished chunks. Each chunk's random numbers come from
``(seed, stage, name, chunk)``, so results are identical for a given seed however many workers
ran. The finished build is assembled inside the partial folder and renamed into place only
when complete; a failed or interrupted bake never leaves a half-written output directory.
"""

from __future__ import annotations

import concurrent.futures as futures
import contextlib
import datetime as dt
import errno
import hashlib
import json
import multiprocessing
import os
import shutil
import signal
import sys
import time
import zlib
from dataclasses import dataclass, field
from functools import partial as partial_fn
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from bake import basisu, chunkio, compress, sunbounce, testskies
from bake import receivers as rx
from bake.denoise import fill_from_nearest, smooth_within_labels, surface_labels
from bake.dome import Dome
from bake.downloads import download_bytes
from bake.gltf import write_site_glb
from bake.irradiance import BounceCache, Estimator, SceneSet, cache_points
from bake.raytrace import Geometry, RayScene
from bake.scene import Site, load_site
from bake.views import mask_image, radiance_image, trace_view, virtual_depth_image
from daylit import __version__
from daylit import manifest as manifest_io
from daylit.stackio import CHANNEL_PATTERN, write_exr, write_stack_exr

# Bump when the meaning of saved chunks changes, so stale partial bakes are not reused.
CHUNK_FORMAT = 3  # 3: .chunk files of .npy records, traced direct light grey (P, n)
BOUNCE_SIGMA_TEXELS = 1.5  # smoothing of the indirect bounce within a surface (texels, pixels)
# An atlas's bounce is smoothed with a local linear fit (bake.denoise: no bias at a surface's
# edges, where the bounce beside a sunlit wall changes fastest); views keep the plain mean.
BOUNCE_ORDER = 1
RAYS_PER_CHUNK = 3_000_000
STAGE_CODES = {"cache": 1, "atlas": 2, "view": 3}


class BakeError(RuntimeError):
    """A bake that cannot proceed for a reason the user can fix (message says how)."""


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


@dataclass
class BakeResult:
    out_dir: Path
    manifest: dict
    duration_s: float
    rays: int
    rays_per_s: float
    stage_s: dict


# --------------------------------------------------------------------------------------------
# Worker processes


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
    cache = None
    if cache_file is not None:
        with np.load(cache_file) as data:
            cache = BounceCache(
                data["points"],
                data["normals"],
                data["faces"],
                data["albedo"],
                {"all": data["E_all"], "real": data["E_real"]},
                geometry,
                float(data["cell_m"]),
            )
    _WORKER["estimator"] = Estimator(dome_vertices, scenes, samples, bounce_rays, cache)


def _run_chunk(task):
    """Compute one chunk in a worker and save it to ``path`` (``{config: array}``, written
    under a temporary name, then renamed); returns the rays cast.

    The worker saves, not the baking process: sending the arrays back (about 5 GB at 400
    lights) made the baking process unpickle and write them all on its own while the
    workers took both cores."""
    points, normals, configs, bounce, seed_words, path = task
    estimator: Estimator = _WORKER["estimator"]
    estimator.rays_cast = 0
    rng = np.random.default_rng(seed_words)
    if bounce:
        out = estimator.basis(points, normals, configs, rng)
    else:
        out = estimator.direct(points, normals, configs, rng)
    chunkio.save_chunk(path, out)
    return estimator.rays_cast


# --------------------------------------------------------------------------------------------


def bake(
    scene_dir,
    out_dir,
    lights=None,
    quality=None,
    workers=None,
    progress=True,
    log=None,
    budget=None,
) -> BakeResult:
    """Bake a site. Raises ``SceneError`` (bad input, nothing written) or ``BakeError``."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    started = time.perf_counter()
    # Absolute from here on: helpers (the KTX2 decoder under Node) run in other directories.
    # The scene's path stays as given: it is only read here, and messages name it as typed.
    out_dir = Path(out_dir).absolute()
    site = load_site(scene_dir, lights=lights, quality=quality, budget=budget)
    compressor = _Compressor(site, log)
    _check_output(out_dir)
    settings = site.settings
    dome = Dome.for_light_count(settings.lights)
    if dome.count != settings.lights:
        log(f"dome: {settings.lights} lights asked, the nearest geodesic dome has {dome.count}")
    workers = workers or os.cpu_count() or 1
    log(
        f"baking {site.name!r}: {dome.count} lights ({dome.kind}, frequency {dome.frequency}), "
        f"quality {settings.quality}, {workers} workers"
    )
    partial = out_dir.parent / f".{out_dir.name}.partial"
    _prepare_partial(partial, _bake_key(site, dome), log)
    stage_s: dict = {}

    t0 = time.perf_counter()
    geometry = _site_geometry(site)
    scenes = SceneSet.build(geometry, site.ground.albedo)
    atlases = _atlases(site, dome, geometry, scenes, log)
    view_hits = {
        view.name: {
            "O": trace_view(view, scenes.scenes["all"], scenes.face_ids["all"], geometry),
            "S": trace_view(view, scenes.scenes["real"], scenes.face_ids["real"], geometry),
        }
        for view in site.views
    }
    for view in site.views:
        log(f"  view {view.name}: {view.width}x{view.height} px")
    stage_s["receivers"] = time.perf_counter() - t0

    samples = max(2, -(-settings.direct_rays // dome.count))
    work = _Work(site, dome, geometry, atlases, view_hits, samples, log)
    with _disk_full_is_a_bake_error(partial):
        rays, trace_s = work.run(partial, workers, progress, stage_s, log)

    t0 = time.perf_counter()
    sun_bounce = _SunBounce.of(site, dome, atlases)
    compressor.start(site, dome, work.stack_names + sun_bounce.stack_names, progress=progress)
    sun_bounce.lights = compressor.selection.selectable
    staging = partial / "build"
    if staging.exists():
        shutil.rmtree(staging)
    (staging / "exr").mkdir(parents=True)
    if site.views:
        (staging / "views").mkdir()
    # Each unit loads its own traced arrays when it starts and lets go of them when done:
    # loading every set first held them all at once (15.8 GB at 400 lights).
    traced = _TracedResults(work.point_sets, partial)
    units = [
        partial_fn(_write_atlas, a, traced, staging, compressor, sun_bounce)
        for a in atlases.values()
    ]
    units += [
        partial_fn(
            _write_view, view, view_hits[view.name], traced, geometry, dome, site, staging,
            compressor,
        )
        for view in site.views
    ]
    try:
        with _disk_full_is_a_bake_error(partial):
            entries = _run_two_at_a_time(units)
    except KeyboardInterrupt:
        log(
            f"interrupted while writing: every traced chunk is kept in {partial}; run the same "
            "command again to resume"
        )
        raise
    manifest_atlases, manifest_views = entries[: len(atlases)], entries[len(atlases) :]
    lightmap_parts = site.virtual + [proxy.part for proxy in site.real]
    albedo_by_part = {p.name: p.albedo.mean(axis=0) for p in lightmap_parts}
    nodes = write_site_glb(staging / "site.glb", site, atlases, albedo_by_part)
    compressor.close()
    stage_s["write"] = time.perf_counter() - t0
    duration = time.perf_counter() - started
    manifest = _manifest(
        site,
        dome,
        nodes,
        manifest_atlases,
        manifest_views,
        compressor,
        {
            "tool": f"daylit {__version__}",
            "quality": settings.quality,
            "seed": settings.seed,
            "samples_per_patch": samples,
            "bounce_rays": settings.bounce_rays,
            "created_utc": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "duration_s": round(duration, 2),
            "rays": int(rays),
            "rays_per_s": round(rays / max(trace_s, 1e-9)),
            "workers": workers,
            "stage_s": {k: round(v, 2) for k, v in stage_s.items()},
        },
    )
    write_manifest(staging, manifest)
    compressor.print_report(manifest, staging)

    _swap_into_place(staging, out_dir)
    shutil.rmtree(partial, ignore_errors=True)
    size = sum(e["bytes"] for e in manifest["files"])
    rate = rays / max(trace_s, 1e-9)
    tracing = (
        f"{rays / 1e6:.1f} M rays at {rate / 1e6:.2f} M rays/s"
        if rays
        else "every chunk re-used from the earlier run"
    )
    log(f"done in {duration:.1f} s: {tracing}; {size / 1e6:.1f} MB in {out_dir}")
    return BakeResult(out_dir, manifest, duration, rays, rate, stage_s)


@contextlib.contextmanager
def _disk_full_is_a_bake_error(partial: Path):
    """A full disk (a 400-light bake keeps about 5 GB of traced chunks and writes 2.4 GB)
    ends the bake with what to do, not a traceback; what was traced is kept."""
    try:
        yield
    except OSError as exc:
        if exc.errno != errno.ENOSPC:
            raise
        raise BakeError(
            f"no space left on the device ({exc}); free space where {partial.parent} is and "
            f"run the same command again: every finished chunk is kept in {partial}"
        ) from exc


def _site_geometry(site: Site) -> Geometry:
    """Every triangle of the site: virtual parts, real proxies, then the ground."""
    parts = site.virtual + [proxy.part for proxy in site.real] + [site.ground.part]
    flags = [True] * len(site.virtual) + [False] * (len(site.real) + 1)
    return Geometry.from_parts(parts, flags)


def _atlases(site: Site, dome: Dome, geometry: Geometry, scenes: SceneSet, log) -> dict:
    """The hull, ground and lightmap atlases (those with any receiver)."""
    settings = site.settings
    texel_scale = settings.texel_scale
    hull_texel = settings.hull_texel_m * texel_scale
    hull_planes = rx.hull_receivers(
        site.virtual,
        hull_texel,
        settings.hull_offset_m,
        settings.min_plane_area_m2,
        settings.max_planes_per_part,
    )
    kept = rx.drop_buried(hull_planes, scenes.scenes["all"])
    if len(kept) < len(hull_planes):
        log(f"  {len(hull_planes) - len(kept)} hull planes lie inside other virtual parts: dropped")
    virtual_scene = RayScene(geometry.subset(geometry.virtual))
    directions = rx.shadow_directions(site, settings.min_sun_elevation_deg, dome.centroids)
    ground_texel = settings.shadow_texel_m * texel_scale
    ground_receivers = rx.ground_receivers(site, directions, virtual_scene, ground_texel)
    wall_receivers = rx.wall_receivers(
        site, directions, virtual_scene, ground_texel, settings.min_plane_area_m2
    )
    atlases = {
        "hull": rx.plane_atlas(
            "hull",
            kept,
            hull_texel,
            {"I": "all", "d": "none"},
            "unoccluded",
            settings.max_atlas_size,
        ),
        "ground": rx.plane_atlas(
            "ground",
            ground_receivers + wall_receivers,
            ground_texel,
            {"I": "all", "d": "real"},
            "real",
            settings.max_atlas_size,
        ),
        "lightmap": rx.lightmap_atlas(
            site.virtual + [proxy.part for proxy in site.real],
            settings.lightmap_texel_m * texel_scale,
            settings.max_atlas_size,
        ),
    }
    for atlas_id in [k for k, a in atlases.items() if a.count == 0]:
        log(f"  atlas {atlas_id}: no receivers, left out of the build")
        del atlases[atlas_id]
    for a in atlases.values():
        log(
            f"  atlas {a.id}: {len(a.receivers)} receivers, {a.width}x{a.height} texels, "
            f"{a.count} sampled, texel {a.texel_m:.3g} m"
        )
    return atlases


class _Work:
    """The points to trace (bounce cache, atlas texels, view hits), chunked, and running them."""

    def __init__(self, site, dome, geometry, atlases, view_hits, samples, log):
        self.site, self.dome, self.geometry, self.samples = site, dome, geometry, samples
        settings = site.settings
        rng = np.random.default_rng([settings.seed, 0])
        self.cache = cache_points(
            geometry, settings.cache_spacing_m, max(2.0, 3 * settings.cache_spacing_m), rng
        )
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
            f"  {len(points)} bounce-cache points; {self.total_points} points in all; "
            f"{samples} rays per light and point, {settings.bounce_rays} bounce rays"
        )

    def run(self, partial: Path, workers: int, progress: bool, stage_s: dict, log):
        """Trace every missing chunk (cache first: the rest gathers its bounce from it).
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
            rays += _run_sets([self.cache_set], partial, seed, init + (None,), workers, bar)
            cache_file = self._save_cache(partial)
            stage_s["cache"] = time.perf_counter() - t0
            t1 = time.perf_counter()
            rays += _run_sets(self.point_sets, partial, seed, init + (cache_file,), workers, bar)
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
        cache_file = partial / "cache.npz"
        tmp = cache_file.with_suffix(".tmp.npz")
        np.savez(
            tmp,
            points=points,
            normals=normals,
            faces=faces,
            albedo=self.geometry.albedo[faces],
            E_all=E["all"],
            E_real=E["real"],
            cell_m=0.5 * self.site.settings.cache_spacing_m,
        )
        os.replace(tmp, cache_file)
        return cache_file


def _run_two_at_a_time(units: list) -> list:
    """Run the write units (callables returning a manifest entry) in two threads; their
    entries in the order given. On a failure or Ctrl-C no other unit starts, the running one
    stops at its next encoder call (:func:`bake.basisu.stop_encoding`), and the error is
    raised once it has stopped: nothing writes into the staging folder afterwards."""
    basisu.allow_encoding()
    with futures.ThreadPoolExecutor(max_workers=2, thread_name_prefix="write") as pool:
        running = [pool.submit(unit) for unit in units]
        try:
            return [future.result() for future in running]
        except BaseException:
            basisu.stop_encoding()
            pool.shutdown(wait=True, cancel_futures=True)
            raise


@dataclass
class _SunBounce:
    """What the sun-bounce stacks need (docs/sun.md, item 5): the lights the sun can be in
    (``compression.selectable_lights``, set once the compressor knows them), the dome's
    upward irradiance per light and the ground's albedo (the closed-form bounce of a hull
    plane's ``d``); ``enabled`` is False when the scene traces no bounce."""

    enabled: bool
    up: np.ndarray  # (n,)
    albedo: np.ndarray  # (3,)
    stack_names: list  # <atlas>.sun_bounce.<stack>, the report's rows
    lights: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @classmethod
    def of(cls, site: Site, dome: Dome, atlases: dict) -> _SunBounce:
        enabled = site.settings.bounce_rays > 0
        names = [
            f"{a.id}.sun_bounce.{stack}" for a in atlases.values() for stack in a.stacks
        ] if enabled else []
        return cls(enabled, dome.cosine_weighted_sr, np.asarray(site.ground.albedo), names)

    def image(self, a, config, bounce, coverage, labels) -> np.ndarray:
        """The one-bounce part of an atlas stack (H, W, n, 3), exactly as
        :func:`_atlas_image` adds it (smoothed within each surface, gutters filled), for the
        lights the sun can be in; zero in the other columns (light i stays column i).
        ``"none"`` (a hull plane's ``d``) has the open ground's bounce in closed form,
        ``albedo E_up_i (1 - n_y) / 2`` (:meth:`Estimator.basis`)."""
        lights = self.lights
        if config == "none":
            lower = 0.5 * (1.0 - a.normals[:, 1])
            part = a.to_image(
                (
                    lower[:, None, None]
                    * self.up[None, lights, None]
                    * self.albedo[None, None, :]
                ).astype(np.float32)
            )
        else:
            part = smooth_bounce(a.to_image(np.ascontiguousarray(bounce[:, lights])), labels)
        part = _dilate(part, coverage, rings=3)
        image = np.zeros((a.height, a.width, len(self.up), 3), dtype=np.float32)
        image[:, :, lights] = part
        return image


def _write_atlas(a, traced: _TracedResults, staging: Path, compressor, sun_bounce) -> dict:
    """Assemble an atlas's stacks (direct plus smoothed bounce, gutters filled), write their
    EXR masters and compact textures; then its sun-bounce stacks (the bounce alone, the
    sun's lights only: :class:`_SunBounce`); returns the atlas's manifest entry."""
    entry = {
        "id": a.id,
        "role": a.role,
        "width": a.width,
        "height": a.height,
        "texel_m": round(a.texel_m, 9),
        "stacks": {},
        "receivers": [r.manifest_entry() for r in a.receivers],
    }
    if a.d_reference:
        entry["d_reference"] = a.d_reference
    coverage = a.coverage()
    labels = a.label_image()
    results = traced.load(a.id)
    images, sun_images = {}, {}
    for stack, config in a.stacks.items():
        direct, bounce = _lookup_result(results, f"{a.id}.{stack}", config)
        images[stack] = _atlas_image(
            a, config, direct, bounce, coverage, _open_labels(a, labels, direct, config)
        )
        rel = f"exr/{a.id}.{stack}.exr"
        write_stack_exr(staging / rel, images[stack])
        entry["stacks"][stack] = {
            "master": rel,
            "quantity": "irradiance",
            "channels": CHANNEL_PATTERN,
        }
        if sun_bounce.enabled and (bounce is not None or config == "none"):
            sun_images[stack] = sun_bounce.image(
                a, config, bounce, coverage, _open_labels(a, labels, direct, config)
            )
    del results, direct, bounce  # the images hold what compression needs
    # Shadowing atlases show I / d: their two stacks are compressed together for it.
    for stack, compact in compressor.run(images, a.id, staging).items():
        entry["stacks"][stack]["compact"] = compact
    del images
    sun_entries = {}
    for stack in list(sun_images):
        image = sun_images.pop(stack)
        rel = f"exr/{a.id}.sun_bounce.{stack}.exr"
        write_stack_exr(staging / rel, image)
        compact = compressor.run_sun_bounce(image, f"{a.id}.sun_bounce.{stack}", staging)
        if compact is not None:
            sun_entries[stack] = {
                "master": rel,
                "quantity": "irradiance",
                "channels": CHANNEL_PATTERN,
                "compact": compact,
            }
    if sun_entries:
        entry["sun_bounce"] = sun_entries
    return entry


def _atlas_image(a, config, direct, bounce, coverage, labels) -> np.ndarray:
    """An atlas stack (H, W, n, 3): direct plus smoothed bounce, gutters filled. ``labels``
    from :func:`_open_labels` (buried texels -2)."""
    image = _rgb(a.to_image(direct), config)
    if bounce is not None:
        image += smooth_bounce(a.to_image(bounce), labels)
    return _dilate(image, coverage, rings=3)


def _open_labels(a, labels: np.ndarray, direct, config: str) -> np.ndarray:
    """The atlas's surface labels (H, W) with its *buried* texels (inside another solid: no
    light from any patch of the dome reaches them, e.g. the ground under a building) marked
    ``-2 - label``: the bounce's smoothing leaves them out (:func:`smooth_bounce`)."""
    if config == "none":
        return labels  # nothing casts: nothing is buried
    seen = a.to_image(np.asarray(direct).reshape(len(direct), -1).max(axis=1) > 0.0)
    out = labels.copy()
    buried = (labels >= 0) & ~seen
    out[buried] = -2 - labels[buried]
    return out


def smooth_bounce(image: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """An atlas's traced bounce (H, W, ...) smoothed within each surface by a local linear
    fit (:data:`BOUNCE_ORDER`) over its open texels; each buried texel (label ``-2 - label``,
    :func:`_open_labels`) takes the smoothed bounce of the nearest open texel of its surface,
    so bilinear filtering at a wall's foot reads open values only (bake.denoise)."""
    smoothed = smooth_within_labels(image, labels, BOUNCE_SIGMA_TEXELS, order=BOUNCE_ORDER)
    surface = np.where(labels <= -2, -2 - labels, labels)
    return fill_from_nearest(smoothed, surface, labels >= 0)


def _rgb(direct: np.ndarray, config: str) -> np.ndarray:
    """Direct light with RGB last, (..., n, 3): a traced configuration's is grey, (..., n),
    and is repeated for R, G, B; ``"none"``'s already has RGB (:meth:`Estimator.basis`)."""
    return direct if config == "none" else np.repeat(direct[..., None], 3, axis=-1)


def _write_view(
    view, hits: dict, traced: _TracedResults, geometry, dome, site, staging: Path, compressor
) -> dict:
    """Assemble a view's O and S (direct plus smoothed bounce), mask and virtual depth, write
    them and the compact textures; returns the view's manifest entry."""
    entry = {
        "id": view.name,
        "width": view.width,
        "height": view.height,
        "K": [[round(float(x), 9) for x in row] for row in view.K],
        "world_from_camera": [[round(float(x), 9) for x in row] for row in view.world_from_camera],
        "camera_convention": "opencv",
        "stacks": {},
    }
    up = dome.cosine_weighted_sr
    results = traced.load(view.name)
    for stack, config in (("O", "all"), ("S", "real")):
        direct, bounce = _lookup_result(results, f"{view.name}.{stack}", config)
        E = _rgb(direct, config)
        if bounce is not None:
            E += view_smoothed(view, hits[stack], bounce, geometry)
        image = radiance_image(view, hits[stack], E, up, site.ground.albedo)
        rel = f"views/{view.name}.{stack}.exr"
        write_stack_exr(staging / rel, image)
        entry["stacks"][stack] = {
            "master": rel,
            "quantity": "radiance",
            "channels": CHANNEL_PATTERN,
            "compact": compressor.run({stack: image}, view.name, staging)[stack],
        }
    entry["mask"] = f"views/{view.name}.mask.png"
    _write_png(staging / entry["mask"], mask_image(view, hits["O"]))
    entry["depth"] = f"views/{view.name}.depth.exr"
    _write_depth(staging / entry["depth"], virtual_depth_image(view, hits["O"]))
    return entry


def _manifest(site, dome, nodes, atlases, views, compressor, bake_info) -> dict:
    return {
        "format": "daylit-build",
        # 2 since a stack's base layers may be split into a UASTC and an ETC1S array
        # (compact.etc1s), which a version-1 client would not sum (docs/manifest.md).
        "version": 2,
        "scene": {
            "id": site.scene_id,
            "name": site.name,
            "latitude_deg": site.latitude_deg,
            "longitude_deg": site.longitude_deg,
            "elevation_m": site.elevation_m,
            "timezone": site.timezone,
            "north_deg": site.north_deg,
        },
        "frame": {"units": "m", "up": "+Y", "east": "+X", "north": "-Z"},
        "dome": dome.to_manifest(),
        "ground": {
            "albedo": [float(a) for a in site.ground.albedo],
            "center_m": list(site.ground.center_m),
            "size_m": list(site.ground.size_m),
        },
        "model": {"path": "site.glb", "nodes": nodes},
        "atlases": atlases,
        "views": views,
        "files": [],
        "compression": compressor.manifest_entry(),
        "bake": bake_info,
    }


def view_smoothed(view, hits, bounce: np.ndarray, geometry: Geometry) -> np.ndarray:
    """The bounce at a view's hit points (P, n, 3), smoothed in image space within the flat
    surface each pixel sees."""
    h, w = view.height, view.width
    image = np.zeros((h * w,) + bounce.shape[1:], dtype=np.float32)
    image[hits.surface] = bounce
    labels = np.full(h * w, -1, dtype=np.int64)
    labels[hits.surface] = surface_labels(geometry.part[hits.faces], hits.normals)
    smoothed = smooth_within_labels(
        image.reshape((h, w) + bounce.shape[1:]), labels.reshape(h, w), BOUNCE_SIGMA_TEXELS
    )
    return smoothed.reshape((h * w,) + bounce.shape[1:])[hits.surface]


def write_manifest(build_dir: Path, manifest: dict) -> None:
    """List every file of ``build_dir`` with size and SHA-256, validate, write manifest.json."""
    files = sorted(p for p in build_dir.rglob("*") if p.is_file() and p.name != "manifest.json")
    manifest["files"] = [manifest_io.file_entry(build_dir, p) for p in files]
    manifest_io.validate(manifest)
    tmp = build_dir / "manifest.json.tmp"
    # Compact separators: phones download this (indenting it would add a third).
    tmp.write_text(json.dumps(manifest, separators=(",", ":")) + "\n", encoding="utf-8")
    os.replace(tmp, build_dir / "manifest.json")


SELECTION_RULE = (
    "top selected_lights of the selectable_lights (every light when absent) by "
    "max(r_i.R, r_i.G, r_i.B) * solid_angle_sr_i, ties to the lower index, zero scores never"
)


class _Compressor:
    """Runs ``bake.compress`` on each stack as it is assembled and keeps the report."""

    def __init__(self, site: Site, log):
        c = site.settings.compression
        self.settings = compress.Settings(
            budget=c["budget"],
            max_rank=c["max_rank"],
            encoding=c["encoding"],
            selected_lights=c["selected_lights"],
        )
        self.log = log
        self.rows: dict[str, dict] = {}  # stack name -> report row (written from two threads)
        self.stack_names: list[str] = []
        self.bar = None
        basisu.basisu_binary()  # fail before baking, not after, when the encoder is missing

    def start(self, site: Site, dome: Dome, stack_names: list[str], progress: bool) -> None:
        """Prepare the test skies, prior and light selection; show a progress bar over the
        stacks ``stack_names`` (``<atlas or view>.<stack>``, the report's order)."""
        self.stack_names = list(stack_names)
        scene = {
            "timezone": site.timezone,
            "latitude_deg": site.latitude_deg,
            "longitude_deg": site.longitude_deg,
            "elevation_m": site.elevation_m,
        }
        # The lights the sun can be in (and the brightest patches of the site's skies with
        # the sun in its patch): the sun-bounce stacks have columns for them.
        selectable = testskies.sun_path_selectable(scene, dome.vertices, dome.solid_angles_sr)
        # Every stack, the fixed views' too, is relit with the sky without the sun's disc
        # (protocol version 2; the kiosk draws the sun itself: web/src/kiosksun.js).
        self.skies, self.S, self.S_inv, self.selection = compress.prepare(
            scene, dome.vertices, dome.solid_angles_sr, self.settings.selected_lights,
            selectable=selectable, sun_in_patch=False,
        )
        self.log(
            f"  {len(self.selection.selectable)} of {dome.count} lights can be selected "
            "(the sun's path and the brightest patches of the site's skies): only they get "
            "their own images, in the sun's bounce and the stacks that select lights"
        )
        self.bar = tqdm(
            total=len(self.stack_names),
            unit="stack",
            disable=not progress,
            desc="writing",
            file=sys.stderr,
            dynamic_ncols=True,
        )

    def run(self, images: dict, prefix: str, staging: Path) -> dict:
        """Compress the stacks ``images`` ({name: (H, W, n, 3)}) of one atlas or fixed view;
        ``I`` and ``d`` together (shadow ratio). Returns {name: compact manifest entry}. Safe
        to call from several threads at once (each with its own stacks)."""
        try:
            results = compress.compress_stacks(
                images, prefix, staging, self.skies, self.S, self.S_inv, self.selection,
                self.settings,
            )
        except basisu.CompressionError as exc:
            raise BakeError(str(exc)) from None
        self.bar.update(len(results))  # tqdm locks its own updates
        out = {}
        stored = max(len(self.selection.selectable), 1)
        for name, result in results:
            # One key per stack: dict assignment is atomic under the GIL.
            self.rows[f"{prefix}.{name}"] = {
                "stack": f"{prefix}.{name}",
                "k": result.entry["k"],
                "error": result.entry["error"]["max"],
                "base_bytes": result.base_bytes,
                "light_bytes": result.light_bytes,
                "light_bytes_per_light": round(result.light_bytes / stored),
                "encode_s": round(result.encode_s, 2),
            }
            out[name] = result.entry
        return out

    def run_sun_bounce(self, image: np.ndarray, name: str, staging: Path) -> dict | None:
        """Compress one sun-bounce stack ``name`` (``<atlas>.sun_bounce.<stack>``) into one
        image per light the sun can be in (:func:`bake.sunbounce.compress_sun_bounce`); its
        compact entry, or None when it is zero everywhere (then the master is dropped too)."""
        try:
            result = sunbounce.compress_sun_bounce(
                image, name, staging, self.selection.selectable, self.settings
            )
        except basisu.CompressionError as exc:
            raise BakeError(str(exc)) from None
        self.bar.update(1)
        if result is None:
            (staging / "exr" / f"{name}.exr").unlink(missing_ok=True)
            return None
        self.rows[name] = {
            "stack": name,
            "k": result.entry["k"],
            "error": result.entry["error"]["max"],
            "base_bytes": 0,
            "light_bytes": result.light_bytes,
            "light_bytes_per_light": round(
                result.light_bytes / max(result.entry["error"]["test_lights"], 1)
            ),
            "encode_s": round(result.encode_s, 2),
        }
        return result.entry

    def close(self) -> None:
        self.bar.close()

    def manifest_entry(self) -> dict:
        return {
            "budget": self.settings.budget,
            "encoding": self.settings.encoding,
            "selected_lights": self.settings.selected_lights,
            "selectable_lights": self.selection.selectable.tolist(),
            "selection": SELECTION_RULE,
            "test_skies": [s.name for s in self.skies],
            "report": self.report(),
        }

    def report(self) -> list[dict]:
        """The report rows in the order of the stacks given to :meth:`start`."""
        return [self.rows[name] for name in self.stack_names if name in self.rows]

    def print_report(self, manifest: dict, staging: Path) -> None:
        budget = self.settings.budget
        self.log(
            f"compact assets ({self.settings.encoding}, budget {budget:.2%} RMS of the "
            f"mean, {self.settings.selected_lights} selected "
            f"light{'' if self.settings.selected_lights == 1 else 's'}):"
        )
        self.log(f"  {'stack':<22}{'k':>4}{'error':>9}{'base':>10}{'lights':>12}{'per light':>11}")
        for row in self.report():
            flag = "" if row["error"] <= budget else "  over budget"
            self.log(
                f"  {row['stack']:<22}{row['k']:>4}{row['error']:>9.2%}"
                f"{row['base_bytes'] / 1e6:>8.2f}MB{row['light_bytes'] / 1e6:>10.2f}MB"
                f"{row['light_bytes_per_light'] / 1e3:>9.1f}kB{flag}"
            )
        sizes = download_bytes(manifest, staging)

        def mb(key: str) -> str:
            return f"{sizes[key] / 1e6:.1f} MB"

        self.log(
            f"  a visitor's phone downloads {mb('phone')} to start, {mb('phone_visit')} over a "
            f"two-hour visit under a clear sky ({sizes['visit_lights']} lights' images per "
            f"stack{'' if sizes['visit_lights'] else ': none, the sky is relit without the sun'}"
            f"); hull-plane mode adds {(sizes['phone_hull'] - sizes['phone']) / 1e6:.1f} MB"
        )
        if manifest["views"]:
            self.log(
                f"  the kiosk downloads {mb('kiosk')} to start, {mb('kiosk_day')} from sunrise "
                f"to sunset ({sizes['day_lights']} lights)"
            )
        self.log(f"  all compact files (what the server offers): {mb('all')}")
        sun_rows = [row for row in self.report() if ".sun_bounce." in row["stack"]]
        if sun_rows:
            default = [r for r in sun_rows if not r["stack"].startswith("hull.")]
            per_light = sum(r["light_bytes_per_light"] for r in default)
            total = sum(r["light_bytes"] for r in sun_rows)
            masters = sum(
                e["bytes"] for e in manifest["files"] if ".sun_bounce." in e["path"]
                and e["path"].startswith("exr/")
            )
            self.log(
                f"  the sun's bounce: one light's images per stack, fetched for the sun's "
                f"patch: {per_light / 1e3:.0f} kB per patch without the hull, "
                f"{mb('sun_bounce_visit')} over the visit ({sizes['visit_sun_patches']} "
                f"patches), {mb('sun_bounce_day')} over a day ({sizes['day_sun_patches']}); "
                f"hull-plane mode adds {mb('sun_bounce_hull_visit')} over the visit"
            )
            self.log(
                f"  the sun's bounce on the server: {total / 1e6:.2f} MB of light images, "
                f"{masters / 1e6:.1f} MB of EXR masters"
            )


# --------------------------------------------------------------------------------------------
# Helpers


def _check_output(out_dir: Path) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise BakeError(f"{out_dir} exists and is not a directory; choose another -o")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not (out_dir / "manifest.json").is_file():
        raise BakeError(
            f"{out_dir} is not empty and is not a daylit build; refusing to replace it "
            "(choose another -o or remove it)"
        )


def _bake_key(site: Site, dome: Dome) -> str:
    h = hashlib.sha256()
    h.update(
        f"daylit {__version__} chunks {CHUNK_FORMAT} dome {dome.kind} {dome.frequency}".encode()
    )
    h.update(repr(sorted(vars(site.settings).items())).encode())
    for path in site.source_files:
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _prepare_partial(partial: Path, key: str, log) -> None:
    key_file = partial / "key.txt"
    if partial.exists():
        if key_file.is_file() and key_file.read_text().strip() == key:
            done = len(list((partial / "chunks").glob("*" + chunkio.SUFFIX)))
            if done:
                log(f"  resuming: {done} chunks already baked in {partial}")
            return
        shutil.rmtree(partial)
    (partial / "chunks").mkdir(parents=True)
    key_file.write_text(key + "\n")


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


class _TracedResults:
    """The traced arrays of the point sets, read from their chunk files on demand."""

    def __init__(self, sets: list[PointSet], partial: Path):
        self.sets, self.partial = sets, partial

    def load(self, owner: str) -> dict:
        """{set name: arrays} of every set of an atlas or view ``owner`` (``<owner>.*``)."""
        return {
            s.name: _load_set(s, self.partial)
            for s in self.sets
            if s.name.split(".")[0] == owner
        }


def _lookup_result(results: dict, name: str, config: str):
    """(direct, bounce or None) of one stack: its configuration's arrays, direct (P, n) grey
    or (P, n, 3), bounce (P, n, 3) (see :meth:`Estimator.basis`)."""
    found = results[name] if name in results else results[name.split(".")[0] + ".shared"]
    return found[config], found.get("bounce:" + config)


def _chunk_path(partial: Path, s: PointSet, index: int) -> Path:
    return partial / "chunks" / f"{s.stage}-{s.name}-{index:05d}{chunkio.SUFFIX}"


def _run_sets(sets, partial, seed, init, workers, bar) -> int:
    """Compute every missing chunk of ``sets`` in a process pool; returns rays cast."""
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
    rays = 0
    with futures.ProcessPoolExecutor(
        max_workers=workers, mp_context=_WORKER_CONTEXT, initializer=_init_worker, initargs=init
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


def _load_set(s: PointSet, partial: Path) -> dict:
    """Every array the set's chunks hold (configurations and their bounces), concatenated."""
    return chunkio.load_chunks([_chunk_path(partial, s, i) for i in range(len(s.chunks))])


def _dilate(image: np.ndarray, coverage: np.ndarray, rings: int) -> np.ndarray:
    """Fill up to ``rings`` texels around covered ones with their covered neighbours' mean,
    so bilinear filtering at chart borders never blends in empty texels."""
    covered = coverage.copy()
    h, w = covered.shape
    for _ in range(rings):
        grown = cv2.dilate(covered.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        ring = np.argwhere(grown & ~covered)
        if len(ring) == 0:
            break
        total = np.zeros((len(ring),) + image.shape[2:], dtype=np.float64)
        count = np.zeros(len(ring))
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
            y = np.clip(ring[:, 0] + dy, 0, h - 1)
            x = np.clip(ring[:, 1] + dx, 0, w - 1)
            ok = covered[y, x]
            total[ok] += image[y[ok], x[ok]]
            count += ok
        image[ring[:, 0], ring[:, 1]] = (
            total / count.reshape((-1,) + (1,) * (total.ndim - 1))
        ).astype(image.dtype)
        covered = grown
    return image


def _write_png(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise BakeError(f"could not write {path}")


def _write_depth(path: Path, depth: np.ndarray) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIPS_COMPRESSION, "type": OpenEXR.scanlineimage}
    write_exr(path, header, {"Z": np.ascontiguousarray(depth, dtype=np.float32)})


def _swap_into_place(staging: Path, out_dir: Path) -> None:
    """Replace ``out_dir`` by ``staging`` with renames only (same file system)."""
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    old = None
    if out_dir.exists():
        old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}"
        os.replace(out_dir, old)
    os.replace(staging, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)

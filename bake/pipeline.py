"""``daylit bake``: from a checked site description to a complete build directory. This
module orchestrates the stages and owns the partial folder; the work of each is elsewhere.

Stages (each split into chunks of points whose layout does not depend on the worker count):

1. **cache** — direct basis irradiance at the bounce-cache points (configurations all, real);
2. **receivers** — direct + one bounce at every texel of the hull, ground and lightmap atlases
   and at every pixel hit of the fixed views (1 and 2: bake.tracework);
3. **write** — stacks into EXR masters and compact textures (bake.writers,
   bake.compressor), masks, ``site.glb``, the coarse start for slow links (bake.coarse),
   ``manifest.json`` (bake.buildmanifest). Atlases and views are written two at a time in
   threads: one's single-threaded parts (EXR writing, quantizing, checking) run while the
   other's encoders use the cores. With a
   cluster the compact textures are made on its workers (bake.compressjobs), as many units
   at a time as it has threads.

Chunks run in a process pool (or on a Dask cluster, ``cluster=ADDRESS``: bake.cluster; the
same bytes either way) and are saved as they finish under ``.<out>.partial/``, keyed by
a hash of every input, so an interrupted bake resumes from its finished chunks. The finished
build is assembled inside the partial folder and renamed into place only when complete
(:func:`bake.writers.swap_into_place`); a failed or interrupted bake never leaves a
half-written output directory.
"""


from __future__ import annotations

import concurrent.futures as futures
import contextlib
import datetime as dt
import errno
import hashlib
import os
import shlex
import shutil
import sys
import time
from dataclasses import dataclass
from functools import partial as partial_fn
from pathlib import Path

from bake import basisu, chunkio, contact, lightmap
from bake import receivers as rx
from bake.blasthreads import one_blas_thread
from bake.buildmanifest import build_manifest, write_manifest
from bake.coarse import CoarseError, add_coarse_entries
from bake.compressor import Compressor
from bake.dome import Dome
from bake.errors import BakeError
from bake.gltf import write_site_glb
from bake.irradiance import SceneSet
from bake.ktx2decoder import close_decoders
from bake.raytrace import Geometry, RayScene
from bake.rowstore import release_freed_memory
from bake.scene import Site, load_site
from bake.sundates import check_sun_up
from bake.tracework import TracedResults, TraceWork
from bake.views import trace_view
from bake.writers import SunBounce, swap_into_place, write_atlas, write_view
from daylit import __version__

# Bump when the meaning of saved chunks changes, so stale partial bakes are not reused.
# 6: bounce-cache points added near contact lines (bake.contact.refine_cache), and a patch
# whose samples all lie below the horizon lit by the share of them unblocked; 5: buried
# texels found by counting the faces crossed (reverted, so chunks saved at 5 are not reused);
# 4: buried texels sampled on contact lines (bake.contact); 3: .npy records.
CHUNK_FORMAT = 6


@dataclass
class BakeResult:
    out_dir: Path
    manifest: dict
    duration_s: float
    rays: int
    rays_per_s: float
    stage_s: dict


def bake(
    scene_dir,
    out_dir,
    lights=None,
    quality=None,
    workers=None,
    progress=True,
    log=None,
    budget=None,
    cluster=None,
    sun_bounce_dates=None,
) -> BakeResult:
    """Bake a site. Raises ``SceneError`` (bad input, nothing written) or ``BakeError``.

    ``cluster``: the address of a Dask scheduler (``tcp://HOST:8786``) whose workers trace
    the chunks instead of a local pool of ``workers`` processes; it is reached before any
    work, and a ``BakeError`` says what to do when it cannot be. ``sun_bounce_dates``
    (:class:`bake.sundates.SunBounceDates`): only the patches the sun crosses on those dates
    get sun-bounce images (None: every patch it crosses in a year)."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    started = time.perf_counter()
    resume = _resume_command(scene_dir, out_dir, lights, quality, budget, sun_bounce_dates)
    # Absolute from here on: helpers (the KTX2 decoder under Node) run in other directories.
    # The scene's path stays as given: it is only read here, and messages name it as typed.
    out_dir = Path(out_dir).absolute()
    site = load_site(scene_dir, lights=lights, quality=quality, budget=budget)
    _check_output(out_dir)
    if sun_bounce_dates is not None:
        check_sun_up(site, sun_bounce_dates)
    client = None
    if cluster is not None:
        from bake.cluster import Cluster

        client = Cluster(cluster, log)
    try:
        compressor = Compressor(site, log, client, sun_bounce_dates)
        return _bake(site, out_dir, compressor, started, workers, client, progress, log, resume)
    finally:
        if client is not None:
            client.close()


def _bake(
    site, out_dir, compressor, started, workers, cluster, progress, log, resume
) -> BakeResult:
    """The stages of :func:`bake` once the site is loaded and the cluster (if any) reached.
    ``resume``: the command that bakes the same site again without ``--cluster``."""
    settings = site.settings
    dome = Dome.for_light_count(settings.lights)
    if dome.count != settings.lights:
        log(f"dome: {settings.lights} lights asked, the nearest geodesic dome has {dome.count}")
    workers = cluster.threads if cluster else workers or os.cpu_count() or 1
    log(
        f"baking {site.name!r}: {dome.count} lights ({dome.kind}, frequency {dome.frequency}), "
        f"quality {settings.quality}, {workers} workers"
        + (f" on the cluster {cluster.address}" if cluster else "")
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
    work = TraceWork(site, dome, geometry, atlases, view_hits, samples, log)
    lost = partial_fn(_cluster_loss_is_a_bake_error, partial, out_dir, resume, cluster,
                      sum(len(s.chunks) for s in [work.cache_set, *work.point_sets]))
    with _disk_full_is_a_bake_error(partial), lost("tracing"):
        rays, trace_s = work.run(partial, workers, progress, stage_s, log, cluster)

    t0 = time.perf_counter()
    # One BLAS thread: the compact textures' bytes then do not depend on the core count, and
    # a cluster's workers (one thread) write the same ones (bake.blasthreads).
    with one_blas_thread():
        sun_bounce = SunBounce.of(site, dome, atlases)
        compressor.start(site, dome, work.stack_names + sun_bounce.stack_names, progress=progress)
        sun_bounce.lights = compressor.selection.selectable
        staging = partial / "build"
        # The atlases' stacks as they are written and read back (bake.rowstore), per unit.
        for folder in (staging, partial / "work"):
            if folder.exists():
                shutil.rmtree(folder)
        (staging / "exr").mkdir(parents=True)
        if site.views:
            (staging / "views").mkdir()
        # Each unit loads its own traced arrays when it starts and lets go of them when done:
        # loading every set first held them all at once (the peak memory: docs/benchmarks.md).
        traced = TracedResults(work.point_sets, partial)
        del scenes  # (the tracing's ray scenes: the write stage casts no rays)
        release_freed_memory()
        units = [
            partial_fn(write_atlas, a, traced, staging, compressor, sun_bounce)
            for a in atlases.values()
        ]
        units += [
            partial_fn(
                write_view, view, view_hits[view.name], traced, geometry, dome, site, staging,
                compressor, sun_bounce,
            )
            for view in site.views
        ]
        try:
            with _disk_full_is_a_bake_error(partial), lost("writing"):
                entries = _run_units(units, _units_at_once(cluster, len(units)))
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
    _write_coarse_start(staging, manifest_atlases, log)
    stage_s["write"] = time.perf_counter() - t0
    duration = time.perf_counter() - started
    manifest = build_manifest(
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

    swap_into_place(staging, out_dir)
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


def _write_coarse_start(staging: Path, manifest_atlases: list[dict], log) -> None:
    """The coarse start for slow links (bake.coarse: each atlas stack's first base layers in
    ``coarse/``), written into the staging folder so that it is published with the build or
    not at all. A base array it cannot cut (ETC1S encoding) leaves the build without one."""
    try:
        added = add_coarse_entries(staging, manifest_atlases)
    except CoarseError as e:
        log(f"  no coarse start for slow links: {e}")
        return
    size = sum((staging / e["ktx2"]).stat().st_size for e in added.values())
    log(f"  coarse start for slow links: {len(added)} stacks, {size / 1e3:.0f} kB")


@contextlib.contextmanager
def _disk_full_is_a_bake_error(partial: Path):
    """A full disk (a bake keeps its traced chunks while it writes the build: the sizes are
    in docs/benchmarks.md) ends the bake with what to do, not a traceback; what was traced
    is kept."""
    try:
        yield
    except OSError as exc:
        if exc.errno != errno.ENOSPC:
            raise
        raise BakeError(
            f"no space left on the device ({exc}); free space where {partial.parent} is and "
            f"run the same command again: every finished chunk is kept in {partial}"
        ) from exc


@contextlib.contextmanager
def _cluster_loss_is_a_bake_error(partial: Path, out_dir: Path, resume: str, cluster,
                                  chunks: int, stage: str):
    """A cluster failure Dask could not get past (bake.cluster.ClusterLostError: a chunk it
    gave up on, no workers, the scheduler gone) ends the bake with what happened, what was
    saved and the commands to resume (with the cluster and on this machine): a content
    team's machines reboot and run out of memory. Nothing is published; the chunks stay."""
    from bake.cluster import ClusterLostError

    try:
        yield
    except ClusterLostError as exc:
        saved = len(list((partial / "chunks").glob("*" + chunkio.SUFFIX)))
        raise BakeError(
            f"the cluster bake stopped while {stage}: {exc}. {saved} of {chunks} traced "
            f"chunks are saved in {partial}; nothing was written to {out_dir}. Resume from "
            f"them with the cluster once its workers are back: `{resume} --cluster "
            f"{cluster.address}`, or on this machine: `{resume}`"
        ) from None


def _resume_command(scene_dir, out_dir, lights, quality, budget, sun_bounce_dates=None) -> str:
    """``daylit bake SCENE -o OUT`` and the options given (paths as the user gave them)."""
    words = ["daylit", "bake", str(scene_dir), "-o", str(out_dir)]
    if lights is not None:
        words += ["--lights", str(lights)]
    if quality is not None:
        words += ["--quality", quality]
    if budget is not None:
        words += ["--budget", repr(budget)]
    if sun_bounce_dates is not None:
        words += ["--sun-bounce-dates", "..".join(sun_bounce_dates.as_list())]
    return shlex.join(words)


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
        "lightmap": lightmap.lightmap_atlas(
            site.virtual + [proxy.part for proxy in site.real],
            settings.lightmap_texel_m * texel_scale,
            settings.max_atlas_size,
        ),
    }
    for atlas_id in ("ground", "lightmap"):  # buried texels' samples onto contact lines
        # Under overlapping solids on the ground only: on the demo's lightmap the same rule
        # moved thousands of texels inside other parts (seen by nobody) and put its
        # compression over the budget on a held-out sky (docs/benchmarks.md, "The
        # courtyard's buried texels under overlapping walls").
        contact.move_buried_samples(atlases[atlas_id], scenes.scenes["all"],
                                    overlaps=atlas_id == "ground")
    for atlas_id in [k for k, a in atlases.items() if a.count == 0]:
        log(f"  atlas {atlas_id}: no receivers, left out of the build")
        del atlases[atlas_id]
    for a in atlases.values():
        log(
            f"  atlas {a.id}: {len(a.receivers)} receivers, {a.width}x{a.height} texels, "
            f"{a.count} sampled, texel {a.texel_m:.3g} m"
        )
    return atlases


def _units_at_once(cluster, units: int) -> int:
    """Write units run at a time: two on this machine (one's single-threaded parts while the
    other's encoders use the cores); with a cluster, whose workers compress, as many as it
    has threads (each running unit holds its stacks in this process's memory)."""
    if cluster is None:
        return 2
    return max(2, min(units, cluster.threads))


def _run_units(units: list, at_once: int) -> list:
    """Run the write units (callables returning a manifest entry) in ``at_once`` threads;
    their entries in the order given. On a failure or Ctrl-C no other unit starts, the
    running ones stop at their next encoder call or cluster wait
    (:func:`bake.basisu.stop_encoding`), and the error is raised once they have stopped:
    nothing writes into the staging folder afterwards. The KTX2 decoders the units started
    (one per thread, bake.ktx2decoder) end with them, whether they succeeded or not."""
    basisu.allow_encoding()
    try:
        with futures.ThreadPoolExecutor(max_workers=at_once, thread_name_prefix="write") as pool:
            running = [pool.submit(unit) for unit in units]
            try:
                return [future.result() for future in running]
            except BaseException:
                basisu.stop_encoding()
                pool.shutdown(wait=True, cancel_futures=True)
                raise
    finally:
        close_decoders()
        # every unit has stopped: encoding in this process may run again (a failed bake
        # left it stopped, and the next compression outside a bake failed at once)
        basisu.allow_encoding()


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

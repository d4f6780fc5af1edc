"""Baking benchmark (issues 2 and 3): bake time, ray throughput and compact-asset sizes.

Bakes the demo site at the given light counts (final quality by default) and prints, for each:

- bake time by stage (receivers, bounce cache, tracing, assembly, compression);
- rays per second achieved by the baker against the *raw* rate of the same ray engine measured
  in the same run on the same geometry with the same number of processes (random occlusion
  rays from points of the site; the goal is at least half);
- the compact assets: k, error and bytes per stack, what a phone and the kiosk download;
- optionally (``--etc1s``) the same stacks encoded with ETC1S instead of UASTC;
- with ``--cluster-workers N``, instead: the same bake on the local process pool and on a Dask
  ``LocalCluster`` of N single-threaded worker processes (``daylit bake --cluster``), one after
  the other in the same run, each stage's seconds and share, and whether every file but the
  manifest is the same byte for byte.

Usage::

    .venv/bin/python benchmarks/bench_bake.py [--lights 160 400] [--quality final] [--etc1s]
    .venv/bin/python benchmarks/bench_bake.py --lights 160 --quality draft --cluster-workers 2

The machine is shared and noisy: read the ratio, not the seconds. Results go in
docs/benchmarks.md by hand.
"""

from __future__ import annotations

import argparse
import concurrent.futures as futures
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bake import compress, stackkinds  # noqa: E402
from bake.downloads import download_bytes  # noqa: E402
from bake.evaluate import Build  # noqa: E402
from bake.pipeline import bake  # noqa: E402
from bake.raytrace import Geometry, RayScene  # noqa: E402
from bake.scene import load_site  # noqa: E402

_GEOMETRY = {}


def _geometry() -> Geometry:
    site = load_site(REPO / "scenes" / "demo")
    parts = site.virtual + [p.part for p in site.real] + [site.ground.part]
    flags = [True] * len(site.virtual) + [False] * (len(site.real) + 1)
    return Geometry.from_parts(parts, flags)


def _raw_worker(seed: int, rays: int) -> tuple[int, float]:
    geometry = _GEOMETRY.setdefault("g", _geometry())
    scene = RayScene(geometry)
    rng = np.random.default_rng(seed)
    lo = geometry.vertices.min(axis=0)
    hi = geometry.vertices.max(axis=0)
    origins = rng.uniform([lo[0] / 3, 0.05, lo[2] / 3], [hi[0] / 3, 12.0, hi[2] / 3], (rays, 3))
    dirs = rng.normal(size=(rays, 3))
    dirs[:, 1] = np.abs(dirs[:, 1])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    scene.occluded(origins[:1000], dirs[:1000])  # warm up
    started = time.perf_counter()
    for start in range(0, rays, 2_000_000):
        scene.occluded(origins[start : start + 2_000_000], dirs[start : start + 2_000_000])
    return rays, time.perf_counter() - started


def raw_ray_rate(workers: int, rays_per_worker: int = 8_000_000) -> float:
    """Occlusion rays per second of Embree alone on the demo, ``workers`` processes at once."""
    with futures.ProcessPoolExecutor(max_workers=workers) as pool:
        results = list(pool.map(_raw_worker, range(workers), [rays_per_worker] * workers))
    return sum(r for r, _ in results) / max(t for _, t in results)


def bench_lights(lights: int, quality: str, workers: int, keep: Path | None) -> dict:
    out = (keep or Path(tempfile.mkdtemp(prefix="daylit-bench-"))) / f"demo-{lights}"
    if out.exists():
        shutil.rmtree(out)
    partial = out.parent / f".{out.name}.partial"
    if partial.exists():
        shutil.rmtree(partial)
    raw_before = raw_ray_rate(workers)
    result = bake(REPO / "scenes" / "demo", out, lights=lights, quality=quality,
                  workers=workers, progress=False, log=lambda m: None)
    raw_after = raw_ray_rate(workers)
    raw = 0.5 * (raw_before + raw_after)
    manifest = result.manifest
    sizes = download_bytes(manifest, out)
    total = sum(f["bytes"] for f in manifest["files"])
    return {
        "lights": manifest["dome"]["count"], "quality": quality, "workers": workers,
        "duration_s": result.duration_s, "stage_s": result.stage_s,
        "rays": result.rays, "rays_per_s": result.rays_per_s, "raw_rays_per_s": raw,
        "raw_spread": abs(raw_before - raw_after) / raw,
        "raw_before_after": [raw_before, raw_after],
        "report": manifest["compression"]["report"],
        "phone_bytes": sizes["phone"], "phone_hull_bytes": sizes["phone_hull"],
        "phone_visit_bytes": sizes["phone_visit"], "visit_lights": sizes["visit_lights"],
        "kiosk_bytes": sizes["kiosk"], "kiosk_day_bytes": sizes["kiosk_day"],
        "day_lights": sizes["day_lights"], "compact_bytes_all": sizes["all"],
        "build_bytes": total, "out": str(out),
    }


def etc1s_comparison(build_dir: Path) -> list[dict]:
    """Recompress every stack of a build with ETC1S and compare with its UASTC report."""
    build = Build(build_dir)
    m = build.manifest
    # As the bake compressed them: every stack with the sky without the sun's disc; in builds
    # that record view_selected_lights (2026-11-24, before the views were fitted without the
    # disc) the views with the sun in its patch and their own selected lights.
    old_views = "view_selected_lights" in m["compression"]
    contexts = {
        view: compress.prepare(
            m["scene"], build.dome_vertices, build.solid_angles,
            m["compression"]["view_selected_lights"] if view and old_views
            else m["compression"]["selected_lights"],
            selectable=build.selection.selectable, sun_in_patch=view and old_views,
        )
        for view in (False, True)
    }
    settings = compress.Settings(encoding="etc1s", budget=m["compression"]["budget"],
                                 selected_lights=m["compression"]["selected_lights"])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for entry in m["atlases"] + m["views"]:
            stacks = {name: build.stack(entry["id"], name) for name in entry["stacks"]}
            started = time.perf_counter()
            skies, S, S_inv, selection = contexts[entry in m["views"]]
            results = stackkinds.compress_stacks(stacks, entry["id"], tmp, skies, S, S_inv,
                                               selection, settings)
            seconds = time.perf_counter() - started
            for name, r in results:
                rows.append({"stack": f"{entry['id']}.{name}", "k": r.entry["k"],
                             "error": r.entry["error"]["max"], "base_bytes": r.base_bytes,
                             "light_bytes": r.light_bytes, "seconds": seconds / len(results)})
    return rows


def print_result(r: dict) -> None:
    s = r["stage_s"]
    print(f"\n== demo, {r['lights']} lights, {r['quality']}, {r['workers']} workers")
    print(f"bake {r['duration_s']:.0f} s: receivers {s.get('receivers', 0):.0f} s, "
          f"cache {s.get('cache', 0):.0f} s, trace {s.get('trace', 0):.0f} s, "
          f"write {s.get('write', 0):.0f} s (EXR masters and compact textures, two atlases "
          f"or views at a time; per-stack encode times below)")
    print(f"rays {r['rays'] / 1e6:.0f} M; baker {r['rays_per_s'] / 1e6:.2f} M rays/s; raw engine "
          f"{r['raw_rays_per_s'] / 1e6:.2f} M rays/s (before {r['raw_before_after'][0] / 1e6:.1f}, "
          f"after {r['raw_before_after'][1] / 1e6:.1f}: spread {r['raw_spread']:.0%}); ratio "
          f"{r['rays_per_s'] / r['raw_rays_per_s']:.2f} (goal >= 0.5)")
    print(f"{'stack':<14}{'k':>4}{'error':>8}{'base MB':>9}{'lights MB':>11}{'kB/light':>10}"
          f"{'encode s':>10}")
    for row in r["report"]:
        print(f"{row['stack']:<14}{row['k']:>4}{row['error']:>8.2%}{row['base_bytes'] / 1e6:>9.2f}"
              f"{row['light_bytes'] / 1e6:>11.1f}{row['light_bytes_per_light'] / 1e3:>10.1f}"
              f"{row['encode_s']:>10.1f}")
    print(f"a phone downloads {r['phone_bytes'] / 1e6:.1f} MB to start "
          f"({r['phone_hull_bytes'] / 1e6:.1f} MB in hull-plane mode), "
          f"{r['phone_visit_bytes'] / 1e6:.1f} MB over a two-hour visit ({r['visit_lights']} "
          f"lights); the kiosk {r['kiosk_bytes'] / 1e6:.1f} MB to start, "
          f"{r['kiosk_day_bytes'] / 1e6:.1f} MB in a day ({r['day_lights']} lights); "
          f"all compact files with the manifest (GLB, KTX2, V: "
          f"what the server offers) {r['compact_bytes_all'] / 1e6:.1f} MB; whole build with EXR "
          f"masters {r['build_bytes'] / 1e6:.0f} MB")


def _file_hashes(build: Path) -> dict:
    """{relative path: SHA-256} of every file of a build but its manifest (which records the
    run's times)."""
    return {
        p.relative_to(build).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(build.rglob("*"))
        if p.is_file() and p.name != "manifest.json"
    }


def bench_cluster(lights: int, quality: str, workers: int, cluster_workers: int,
                  keep: Path | None) -> dict:
    """The demo baked by the local pool of ``workers`` processes, then on a LocalCluster of
    ``cluster_workers`` single-threaded processes: {"local", "cluster": (seconds, stage
    seconds)}, "identical": every file but the manifest the same."""
    from distributed import LocalCluster

    parent = keep or Path(tempfile.mkdtemp(prefix="daylit-bench-"))
    runs = {}
    for mode in ("local", "cluster"):
        out = parent / f"demo-{lights}-{mode}"
        for path in (out, out.parent / f".{out.name}.partial"):
            if path.exists():
                shutil.rmtree(path)
        common = {"lights": lights, "quality": quality, "progress": False, "log": lambda m: None}
        if mode == "local":
            result = bake(REPO / "scenes" / "demo", out, workers=workers, **common)
        else:
            with LocalCluster(n_workers=cluster_workers, threads_per_worker=1, processes=True,
                              dashboard_address=None) as cluster:
                result = bake(REPO / "scenes" / "demo", out, cluster=cluster.scheduler_address,
                              **common)
        runs[mode] = (result.duration_s, result.stage_s, _file_hashes(out))
    identical = runs["local"][2] == runs["cluster"][2]
    if not keep:
        shutil.rmtree(parent, ignore_errors=True)
    return {"lights": lights, "quality": quality, "workers": workers,
            "cluster_workers": cluster_workers, "identical": identical,
            "local": runs["local"][:2], "cluster": runs["cluster"][:2]}


def print_cluster(r: dict) -> None:
    print(f"\n== demo, {r['lights']} lights, {r['quality']}: local pool of {r['workers']} "
          f"processes against a LocalCluster of {r['cluster_workers']} workers")
    for mode in ("local", "cluster"):
        duration, stages = r[mode]
        shares = ", ".join(f"{name} {s:.1f} s ({s / duration:.0%})" for name, s in stages.items())
        print(f"{mode:>8}: {duration:.1f} s: {shares}")
    print(f"every file but the manifest byte-identical: {r['identical']}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lights", type=int, nargs="+", default=[160, 400])
    parser.add_argument("--quality", choices=("draft", "final"), default="final")
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    parser.add_argument("--etc1s", action="store_true", help="also recompress with ETC1S")
    parser.add_argument("--keep", type=Path, help="keep the builds in this folder")
    parser.add_argument("--json", type=Path, help="write the figures as JSON")
    parser.add_argument("--cluster-workers", type=int, metavar="N",
                        help="compare the local pool with a Dask LocalCluster of N workers")
    args = parser.parse_args()
    results = []
    if args.cluster_workers:
        for lights in args.lights:
            r = bench_cluster(lights, args.quality, args.workers, args.cluster_workers, args.keep)
            print_cluster(r)
            results.append(r)
        if args.json:
            args.json.write_text(json.dumps(results, indent=1, default=float))
        return 0
    for lights in args.lights:
        r = bench_lights(lights, args.quality, args.workers, args.keep)
        print_result(r)
        if args.etc1s:
            rows = etc1s_comparison(Path(r["out"]))
            r["etc1s"] = rows
            print("ETC1S instead of UASTC:")
            for row in rows:
                print(f"  {row['stack']:<14}{row['k']:>4}{row['error']:>8.2%}"
                      f"{row['base_bytes'] / 1e6:>9.2f} MB base {row['light_bytes'] / 1e6:>8.1f}"
                      f" MB lights {row['seconds']:>7.1f} s")
        results.append(r)
        if not args.keep:
            shutil.rmtree(Path(r["out"]).parent, ignore_errors=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Issue 20 (part): the ground at the foot of walls and more than one bounce, measured.

Three measurements, printed in one run (docs/benchmarks.md, "Contact lines and bounces"),
after the choice of method on the analytic field (``--methods`` prints only that, in a
second):

0. **The contact-line methods on the analytic field**: the direct light beside an infinite
   wall of height 2, 3 and 5 m on 0.5 m texels, the foot at 25 places inside a texel, read
   bilinearly 5 cm, 25 cm and 1 m from the wall; the worst error of each way to fill the
   buried texel (the set-up of tests/bake/test_contact_fill.py).

1. **Accuracy within 0.5 m of walls**, before and after: an L-shaped courtyard (two 3 m
   walls, 1 m thick, albedo 0.6 everywhere, 0.5 m ground texels as the demo's, 160 lights,
   the final level's rays) baked twice in this process: *before* (contact lines off:
   ``bake.contact.ENABLED = False``, one bounce: the bake before issue 20) and *after* (on,
   the default bounces). Each build is read at ground points
   0.02-0.5 m from the walls (both faces of both walls, and the inner corner's diagonal) and
   compared with an independent reference: Monte Carlo paths through trimesh's ray queries
   with 30 bounces (tests/bake/paths.py).
2. **Bake time**: the courtyard's two bakes by stage (the cache stage holds the added
   bounces), and the added work of bounces = 1, 2, 3 alone on the demo's geometry at the
   final level (its bounce cache's own gather and products,
   :func:`bake.irradiance.cache_bounces`; nothing else in the bake changes with N).
3. **The default number of bounces**: on the demo's geometry with every albedo 0.6 under a
   uniform sky, the mean shortfall of N bounces at ground and model texels against 12.

Usage: ``PYTHONPATH=. nice -n 10 .venv/bin/python benchmarks/bench_contact.py [--quick]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bake import contact  # noqa: E402
from bake.evaluate import Build  # noqa: E402
from bake.pipeline import bake  # noqa: E402
from bake.scene_schema import DEFAULT_BOUNCES  # noqa: E402
from tests.bake.paths import PathReference  # noqa: E402
from tests.bake.test_contact import _courtyard, _ground_mesh  # noqa: E402
from tests.sites import make_site  # noqa: E402

ALBEDO = 0.6
QUIET = {"progress": False, "log": lambda msg: None}


def courtyard_bake(root: Path, bounces: int, enabled: bool, lights: int) -> tuple:
    contact.ENABLED = enabled
    try:
        scene = make_site(
            root / "scene", virtual=_courtyard(), ground_albedo=(ALBEDO,) * 3, ground_m=50.0,
            lights=lights, direct_rays=960, bounce_rays=96, bounces=bounces,
            ground_texel_m=0.5, lightmap_texel_m=0.2,
        )
        t0 = time.perf_counter()
        result = bake(scene, root / "build", **QUIET)
        return Build(root / "build"), time.perf_counter() - t0, result.stage_s
    finally:
        contact.ENABLED = True


def near_wall_points(rng, count: int) -> np.ndarray:
    """Ground points 0.02-0.5 m from the courtyard's walls, spread over the four long faces
    and the inner corner's diagonal. (count, 3)."""
    d = rng.uniform(0.02, 0.5, count)
    s = rng.uniform(1.0, 10.0, count)
    kind = np.arange(count) % 5
    x = np.select([kind == 0, kind == 1, kind == 2, kind == 3], [s, d, s, -1.0 - d], d)
    z = np.select([kind == 0, kind == 1, kind == 2, kind == 3], [d, s, -1.0 - d, s], d)
    x[kind == 2] = s[kind == 2] + 0.5  # the outer face of wall_a: beyond wall_b's end
    return np.stack([x, np.zeros(count), z], axis=1), d


def errors(build: Build, points, reference) -> np.ndarray:
    baked = np.array([build.irradiance(p, [0, 1, 0], "uniform:1")["with"][0] for p in points])
    return baked / reference - 1.0


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="40 lights, fewer points/paths")
    parser.add_argument("--methods", action="store_true", help="only measurement 0")
    args = parser.parse_args()
    methods_on_the_analytic_wall()
    if args.methods:
        return
    lights = 40 if args.quick else 160
    count, paths = (15, 5000) if args.quick else (60, 20000)
    rng = np.random.default_rng(2026)
    points, distance = near_wall_points(rng, count)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        runs = {}
        for name, bounces, enabled in (("before", 1, False), ("after", DEFAULT_BOUNCES, True)):
            runs[name] = courtyard_bake(root / name, bounces, enabled, lights)
            print(f"baked {name}: {runs[name][1]:.1f} s", flush=True)
        build = runs["after"][0]
        ref = PathReference([(m, a[0]) for _, m, a in _courtyard()] + [(_ground_mesh(build),
                            ALBEDO)], ground_albedo=ALBEDO)
        t0 = time.perf_counter()
        by_k = np.array([ref.by_bounces(p, [0, 1, 0], paths, 30, rng) for p in points])
        print(f"reference: {count} points x {paths} paths, 30 bounces, "
              f"{time.perf_counter() - t0:.1f} s")
        full = by_k.sum(axis=1)
        print("\n1. accuracy within 0.5 m of walls (uniform sky, albedo 0.6), baked / paths - 1")
        print("   run       bounces  reference   mean     RMS   d<0.1m mean  worst")
        near = distance < 0.1
        for name, bounces, label in (("before", 1, "1 bounce"), ("before", 1, "full"),
                                     ("after", DEFAULT_BOUNCES, f"{DEFAULT_BOUNCES} bounces"),
                                     ("after", DEFAULT_BOUNCES, "full")):
            reference = full if label == "full" else by_k[:, : bounces + 1].sum(axis=1)
            e = errors(runs[name][0], points, reference)
            print(f"   {name:8s}  {bounces:7d}  {label:9s} {100 * e.mean():+6.2f}% "
                  f"{100 * np.sqrt((e ** 2).mean()):6.2f}%  {100 * e[near].mean():+8.2f}%   "
                  f"{100 * e[np.argmax(np.abs(e))]:+6.2f}%")
        direct_share = (by_k[:, 0] / full).mean()
        print(f"   (direct light is {100 * direct_share:.0f} % of the total there; "
              f"{near.sum()} of {count} points closer than 0.1 m)")
        print("\n2. bake time of the courtyard (same machine, same run)")
        for name in ("before", "after"):
            _, seconds, stage = runs[name]
            print(f"   {name}: {seconds:6.1f} s in all, cache stage "
                  f"{stage.get('cache', 0):5.1f} s, trace {stage.get('trace', 0):5.1f} s, "
                  f"write {stage.get('write', 0):5.1f} s")
    demo_bounces()


def methods_on_the_analytic_wall() -> None:
    import tests.bake.test_contact_fill as field
    from bake.contact import continue_into_buried, extrapolate_direct
    from bake.evaluate import _bilinear

    print("0. filling the buried texel, analytic wall field, worst over 25 foot positions")
    print("   wall  method          5 cm      25 cm     1 m")
    for h_m in (2.0, 3.0, 5.0):
        for method in ("dark (before)", "plane", "contact value", "chord (chosen)"):
            worst = np.zeros(3)
            for foot in field.FEET_M:
                moved = method in ("contact value", "chord (chosen)")
                values, labels, atlas = field._row(foot, h_m, moved=moved)
                row = 0.5
                if method == "chord (chosen)":
                    image = extrapolate_direct(atlas, values[:, None])[None]
                elif method == "plane":
                    image = continue_into_buried(
                        np.repeat(values[None, :, None], 5, 0).astype(np.float32),
                        np.repeat(labels[None], 5, 0))
                    row = 2.5
                else:
                    image = values[None, :, None]
                for k, x in enumerate((0.05, 0.25, 1.0)):
                    e = _bilinear(image, (foot + x) / 0.5, row)[0] / field.wall_foot(x, h_m) - 1
                    worst[k] = e if abs(e) > abs(worst[k]) else worst[k]
            print(f"   {h_m:.0f} m   {method:14s} " + " ".join(f"{100 * w:+7.2f}%" for w in worst))


def demo_bounces() -> None:
    """Measurements 2 (the demo's added work) and 3 (the default)."""
    from bake.cachepoints import cache_points
    from bake.dome import Dome
    from bake.irradiance import BounceCache, Estimator, SceneSet, cache_bounces
    from bake.pipeline import _site_geometry
    from bake.scene import load_site

    site = load_site(REPO / "scenes" / "demo", quality="final")
    geometry = _site_geometry(site)
    geometry.albedo[:] = ALBEDO
    ground_albedo = np.full(3, ALBEDO)
    s = site.settings
    rng = np.random.default_rng(1)
    points, normals, faces = cache_points(geometry, s.cache_spacing_m,
                                          max(2.0, 3 * s.cache_spacing_m), rng)
    print(f"\n3. the demo at albedo 0.6, uniform sky: {len(points)} cache points, "
          f"{s.bounce_rays} gather rays")
    scenes = SceneSet.build(geometry, ground_albedo)
    dome = Dome.for_light_count(40)
    direct = Estimator(dome.vertices, scenes, 8, 0)
    E = direct.direct(points, normals, ("all",), rng)["all"].sum(axis=1, keepdims=True)
    # One light holding the whole uniform sky: E is the sum over the 40 patches.
    one = Dome.for_light_count(40).vertices[:1]
    up = float(direct.up_irradiance.sum())
    cache = BounceCache(points, normals, faces, geometry.albedo[faces], {"all": E}, geometry,
                        0.5 * s.cache_spacing_m)
    est = Estimator(one, scenes, 2, s.bounce_rays, cache)
    est.up_irradiance = np.array([up])  # the open ground beyond: the whole sky's E_up
    # Receivers: texels of the ground and the models near the buildings (a sample).
    from bake.pipeline import _atlases

    atlases = _atlases(site, Dome.for_light_count(s.lights), geometry, scenes, lambda m: None)
    pick = np.random.default_rng(3)
    receivers = []
    for a in (atlases["ground"], atlases["lightmap"]):
        k = pick.choice(a.count, min(4000, a.count), replace=False)
        receivers.append((a.points[k], a.normals[k]))
    rp = np.concatenate([r[0] for r in receivers])
    rn = np.concatenate([r[1] for r in receivers])
    Er = direct.direct(rp, rn, ("all",), np.random.default_rng(4))["all"].sum(axis=1)
    totals = {}
    for N in (1, 2, 3, 4, 5, 6, 8, 12):
        own = cache_bounces(est, N, np.random.default_rng(5))
        c = BounceCache(points, normals, faces, geometry.albedo[faces], {"all": E}, geometry,
                        0.5 * s.cache_spacing_m, own)
        e2 = Estimator(one, scenes, 2, s.bounce_rays, c)
        e2.up_irradiance = np.array([up])
        b = e2.bounce(rp, rn, "all", np.random.default_rng(6))[:, 0, 0]
        totals[N] = Er + b
    open_ = Er > 0
    print("   N   mean shortfall against 12   RMS     95th percentile")
    for N, t in totals.items():
        short = 1.0 - t[open_] / totals[12][open_]
        rms = 100 * np.sqrt((short**2).mean())
        print(f"   {N:2d}  {100 * short.mean():6.2f} %{rms:24.2f} %"
              f"  {100 * np.percentile(short, 95):5.2f} %")
    print(f"\n2b. the added work on the demo at the final level ({s.lights} lights, "
          f"{len(points)} cache points):")
    big = Dome.for_light_count(s.lights)
    E_big = {"all": np.repeat(E, big.count, axis=1) / big.count,
             "real": np.repeat(E, big.count, axis=1) / big.count}
    cache = BounceCache(points, normals, faces, geometry.albedo[faces], E_big, geometry,
                        0.5 * s.cache_spacing_m)
    est = Estimator(big.vertices, scenes, 2, s.bounce_rays, cache)
    for N in (1, 2, 3):
        t0 = time.perf_counter()
        cache_bounces(est, N, np.random.default_rng(5))
        print(f"   bounces {N}: {time.perf_counter() - t0:6.1f} s (one process)")


if __name__ == "__main__":
    main()

"""A build's compact stacks on held-out skies, and what its clients download (issue 15 item 8).

For every stack: k, the selected lights, the worst RMS error on the test skies (the bake's
record) and on the held-out skies (``bake.testskies.held_out_skies``: without the sun's disc,
as the client relights them; for the views of builds made before they were too, with it in
its patch), decoded as the client decodes them; the ground's and the hull's worst
shadow-ratio error on the held-out skies; then the downloads (``bake/downloads.py``) and the
bake's time.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/sky_only_budget.py BUILD [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bake import testskies  # noqa: E402
from bake.downloads import download_bytes  # noqa: E402
from bake.evaluate import Build  # noqa: E402


def measure(build_dir: Path) -> dict:
    build = Build(build_dir)
    m = build.manifest
    site = m["scene"]
    views = {v["id"] for v in m["views"]}
    # The views relight with the sky without the disc too, but in builds of 2026-11-24 made
    # before that (they record the views' own ``view_selected_lights``) with the sun in its
    # patch (docs/compact-assets.md, "The fixed views too").
    views_in_patch = "view_selected_lights" in m["compression"]
    held = {
        flag: {s.name: s.r for s in testskies.held_out_skies(site, build.dome_vertices, flag)}
        for flag in (False, True)
    }
    report = {row["stack"]: row for row in m["compression"]["report"]}
    rows = []
    for owner in m["atlases"] + m["views"]:
        for name, stack in owner["stacks"].items():
            key = f"{owner['id']}.{name}"
            valid = np.any(build.stack(owner["id"], name) != 0.0, axis=(2, 3))
            errors = {}
            for sky, r in held[owner["id"] in views and views_in_patch].items():
                master = build.composite(owner["id"], name, r, "master")[valid]
                decoded = build.composite(owner["id"], name, r, "compact")[valid]
                errors[sky] = float(np.sqrt(((decoded - master) ** 2).mean()) / master.mean())
            rows.append({
                "stack": key, "k": stack["compact"]["k"],
                "selected_lights": stack["compact"].get(
                    "selected_lights", m["compression"]["selected_lights"]),
                "test_max": stack["compact"]["error"]["max"],
                "held_out_max": max(errors.values()),
                "held_out": errors,
                "base_bytes": report[key]["base_bytes"],
                "light_bytes": report[key]["light_bytes"],
            })
    ratios = {}
    for atlas in ("ground", "hull"):
        if atlas not in build.atlases:
            continue
        worst = {}
        for sky, r in held[False].items():
            d_master = build.composite(atlas, "d", r, "master")
            ratio_master = build.composite(atlas, "I", r, "master") / np.maximum(d_master, 1e-9)
            d_compact = build.composite(atlas, "d", r, "compact")
            ratio_compact = build.composite(atlas, "I", r, "compact") / np.maximum(
                d_compact, 1e-9)
            lit = d_master > 0.05 * d_master[d_master > 0].mean()
            error = np.abs(ratio_compact - ratio_master)[lit]
            worst[sky] = {"max": float(error.max()), "p999": float(np.percentile(error, 99.9))}
        ratios[atlas] = worst
    sizes = download_bytes(m, build.dir)
    sun_bounce = sum(r["light_bytes"] for r in m["compression"]["report"]
                     if ".sun_bounce." in r["stack"])
    return {
        "lights": m["dome"]["count"], "quality": m["bake"]["quality"],
        "bake_s": m["bake"]["duration_s"], "stage_s": m["bake"]["stage_s"],
        "budget": m["compression"]["budget"], "stacks": rows, "ratio": ratios,
        "downloads": sizes, "sun_bounce_offered": sun_bounce,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    out = measure(args.build)
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"{out['lights']} lights, {out['quality']}, bake {out['bake_s']:.0f} s "
          f"(stages {out['stage_s']}); budget {out['budget']:.2%}")
    print(f"{'stack':<14}{'k':>4}{'m':>3}{'test':>8}{'held-out':>10}{'base':>9}{'lights':>9}")
    for r in out["stacks"]:
        print(f"{r['stack']:<14}{r['k']:>4}{r['selected_lights']:>3}{r['test_max']:>8.2%}"
              f"{r['held_out_max']:>10.2%}{r['base_bytes'] / 1e6:>7.2f}MB"
              f"{r['light_bytes'] / 1e6:>7.2f}MB")
    for atlas, worst in out["ratio"].items():
        print(f"{atlas} shadow ratio on held-out skies, worst texel (99.9th percentile): "
              + ", ".join(f"{s} {w['max']:.4f} ({w['p999']:.4f})" for s, w in worst.items()))
    d = out["downloads"]
    print(f"phone {d['phone'] / 1e6:.2f} MB to start, {d['phone_visit'] / 1e6:.2f} MB over the "
          f"visit ({d['visit_lights']} lights), hull-plane mode {d['phone_hull'] / 1e6:.2f} MB; "
          f"sun's bounce {d['sun_bounce_start'] / 1e6:.2f} MB at start, "
          f"{d['sun_bounce_visit'] / 1e6:.2f} MB over the visit")
    print(f"kiosk {d['kiosk'] / 1e6:.2f} MB to start, {d['kiosk_day'] / 1e6:.2f} MB over a day "
          f"({d['day_lights']} lights)")
    print(f"server offers {d['all'] / 1e6:.1f} MB, of which the sun's bounce images "
          f"{out['sun_bounce_offered'] / 1e6:.1f} MB")


if __name__ == "__main__":
    main()

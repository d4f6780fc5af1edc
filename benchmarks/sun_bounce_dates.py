"""A site baked for the whole year and for some dates, in the same run, then the dated build's
sun-bounce images made again for other dates (``daylit bake --sun-bounce-dates``, ``daylit
sun-bounce``; docs/sun.md "The sun's bounce for the dates served", docs/benchmarks.md).
Prints for each: the bake's stages and its write share (issues 20), what the server offers
and what a phone downloads over a two-hour visit with the sun's bounce (issue 15; the visit
on the first of the dates for a dated build), and the time of the remake.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/sun_bounce_dates.py SCENE WORKDIR
        [--lights 400] [--quality final] [--dates 2027-04-06..2027-04-12]
        [--remake 2027-04-13..2027-04-13] [--skip-year]

The bakes run one after another in this process (the whole year first: each is the other's
baseline); WORKDIR gets ``year/``, ``dates/`` and ``remade/`` (a copy of ``dates/``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bake.downloads import download_bytes  # noqa: E402
from bake.pipeline import bake  # noqa: E402
from bake.sundates import SunBounceDates  # noqa: E402
from bake.sunremake import remake_sun_bounce  # noqa: E402


def cpu_s() -> float:
    """This process's and its finished children's CPU seconds (user + system)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def figures(build: Path) -> dict:
    """What the manifest says of a build's bake and what its clients download."""
    manifest = json.loads((build / "manifest.json").read_text())
    stages = manifest["bake"]["stage_s"]
    rows = manifest["compression"]["report"]
    sizes = download_bytes(manifest, build)
    return {
        "bake_s": manifest["bake"]["duration_s"],
        "stages": stages,
        "write_share": stages["write"] / manifest["bake"]["duration_s"],
        "sun_bounce_encode_s": sum(r["encode_s"] for r in rows if ".sun_bounce." in r["stack"]),
        "all_encode_s": sum(r["encode_s"] for r in rows),
        "offered": sizes["all"],
        "phone_visit": sizes["phone_visit_with_sun_bounce"],
        "dates": manifest["compression"].get("sun_bounce_dates"),
    }


def show(label: str, f: dict, wall_s: float, cpu: float) -> None:
    stages = ", ".join(f"{k} {v:.1f}" for k, v in f["stages"].items())
    print(f"{label} (dates {f['dates']}): bake {f['bake_s']:.1f} s (wall {wall_s:.1f} s, "
          f"CPU {cpu:.0f} s); {stages}; write share {100 * f['write_share']:.1f} %")
    print(f"  compression: sun's bounce {f['sun_bounce_encode_s']:.1f} s of "
          f"{f['all_encode_s']:.1f} s; the server offers {f['offered']:,} B, a phone's visit "
          f"{f['phone_visit']:,} B ({f['offered'] / f['phone_visit']:.2f} times)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("workdir", type=Path)
    ap.add_argument("--lights", type=int, default=400)
    ap.add_argument("--quality", default="final", choices=("draft", "final"))
    ap.add_argument("--dates", default="2027-04-06..2027-04-12")
    ap.add_argument("--remake", default="2027-04-13..2027-04-13")
    ap.add_argument("--skip-year", action="store_true", help="no whole-year bake")
    args = ap.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    quiet = lambda msg: None  # noqa: E731
    runs = [("dates", SunBounceDates.parse(args.dates))]
    if not args.skip_year:
        runs.insert(0, ("year", None))
    for label, dates in runs:
        out = args.workdir / label
        shutil.rmtree(out, ignore_errors=True)
        cpu0, t0 = cpu_s(), time.perf_counter()
        bake(args.scene, out, lights=args.lights, quality=args.quality, progress=False,
             log=quiet, sun_bounce_dates=dates)
        show(label, figures(out), time.perf_counter() - t0, cpu_s() - cpu0)
    remade = args.workdir / "remade"
    shutil.rmtree(remade, ignore_errors=True)
    shutil.copytree(args.workdir / "dates", remade)
    cpu0, t0 = cpu_s(), time.perf_counter()
    remake_sun_bounce(args.scene, remade, SunBounceDates.parse(args.remake), progress=False,
                      log=quiet)
    wall, cpu = time.perf_counter() - t0, cpu_s() - cpu0
    f = figures(remade)
    print(f"remade for {f['dates']}: {wall:.1f} s (CPU {cpu:.0f} s); the server offers "
          f"{f['offered']:,} B, a phone's visit {f['phone_visit']:,} B "
          f"({f['offered'] / f['phone_visit']:.2f} times)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

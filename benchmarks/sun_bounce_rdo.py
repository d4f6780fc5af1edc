"""A build's sun-bounce images of a visit in plain UASTC and with RDO at several lambdas and
UASTC levels: bytes, the encoders' time, and the bake's own judge as displayed (RMS, and the
99th percentile per texel; bake.sundisplay.DisplayCheck) against each patch's master column
(issue 15 item 8; what chose ``bake.sunbounce.PLAIN_TEXEL_SLACK``, docs/benchmarks.md "The
phone's visit under 4 MB", and the RDO dictionary, "The RDO dictionary").

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/sun_bounce_rdo.py BUILD [--atlas lightmap]
        [--lights 117,97,75,91,67,83] [--tries 0:,0:0.1,0:0.25,1:0.1:4096]

``--tries``: ``LEVEL:LAMBDA[:DICTIONARY]`` (an empty lambda: no RDO; the dictionary in bytes,
by default the bake's ``sun_bounce_rdo_dictionary_bytes``); the visit's patches by default
(``bake.downloads.VISIT``). Each try's time is the wall time of its encode and its encoders'
CPU, the tries run one after another in the same process (each the other's baseline).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bake import downloads  # noqa: E402
from bake.basisu import encode  # noqa: E402
from bake.compresssettings import Settings  # noqa: E402
from bake.evaluate import Build  # noqa: E402
from bake.ktx2decoder import decode  # noqa: E402
from bake.quantize import quantized_png  # noqa: E402
from bake.rowstore import as_stack  # noqa: E402
from bake.sundisplay import DisplayCheck, DisplaySkies  # noqa: E402
from daylit.stackio import read_stack_exr  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--atlas", default="lightmap")
    parser.add_argument("--lights", default=None, help="sun-path patches (default: a visit's)")
    parser.add_argument("--tries", default="0:,0:0.1,0:0.25,0:0.5,0:1,1:0.1,2:0.1")
    args = parser.parse_args()
    build = Build(args.build)
    m = build.manifest
    owner = next(a for a in m["atlases"] if a["id"] == args.atlas)
    lights = ([int(i) for i in args.lights.split(",")] if args.lights
              else downloads.sun_patches_over(m, *downloads.VISIT))
    skies = DisplaySkies.of_dome(build.dome_vertices, build.solid_angles,
                                 build.selection.selectable, m["scene"]["elevation_m"])
    bounce = as_stack(read_stack_exr(args.build / owner["sun_bounce"]["I"]["master"]))
    sky = read_stack_exr(args.build / owner["stacks"]["I"]["master"])
    check = DisplayCheck(sky, skies, lights, bounce=bounce)
    shown = check.shown_but_bounce(lights)
    columns = bounce.columns(lights)
    settings = Settings()
    print(f"{args.atlas} I, patches {lights}: bytes, then RMS as displayed / 99th percentile "
          "per texel for each")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        quantized = {i: quantized_png(columns[j], tmp / f"x.L{i:04d}.png")
                     for j, i in enumerate(lights)}
        for n, tried in enumerate(args.tries.split(",")):
            level, lam, *dictionary = tried.split(":")
            try_settings = settings if not dictionary else replace(
                settings, sun_bounce_rdo_dictionary_bytes=int(dictionary[0]))
            out = tmp / f"try{n}"
            out.mkdir()
            wall, cpu = time.perf_counter(), _children_cpu_s()
            encode([q.path for q in quantized.values()], out, try_settings, array=False,
                   level=int(level), rdo_lambda=float(lam) if lam else None)
            wall, cpu = time.perf_counter() - wall, _children_cpu_s() - cpu
            files = [out / f"x.L{i:04d}.ktx2" for i in lights]
            row = []
            for j, (i, decoded) in enumerate(zip(lights, decode(files), strict=True)):
                rms, p99 = check.errors(i, shown[j], columns[j],
                                        quantized[i].value(decoded[0]))
                row.append(f"{i}: {files[j].stat().st_size / 1e3:.1f} kB "
                           f"{100 * rms:.2f} / {100 * p99:.1f} %")
            total = sum(f.stat().st_size for f in files)
            rdo = (f"RDO {lam}, dictionary "
                   f"{try_settings.sun_bounce_rdo_dictionary_bytes} B" if lam else "no RDO")
            print(f"level {level}, {rdo}: {total:,} B, encode {wall:.1f} s "
                  f"(encoders' CPU {cpu:.1f} s) | " + " | ".join(row), flush=True)
    check.remove()


def _children_cpu_s() -> float:
    """CPU seconds of this process's ended children (the encoders)."""
    t = os.times()
    return t.children_user + t.children_system


if __name__ == "__main__":
    main()

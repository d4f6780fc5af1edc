"""The fixed views' sun-bounce images against their masters, as the bake judges them and as
displayed (docs/benchmarks.md, "The kiosk's sun bounce").

    python benchmarks/kiosk_sun_bounce_error.py BUILD [--dni W_M2]

Per stack (O, S) of the first view and per sun-path light ``p`` above 2 degrees: the column
decoded as the client decodes it, its RMS error over the view's surface pixels relative to
(a) the column's own mean (the bake's check) and (b) the mean of what the kiosk shows there
without the sun's direct term: the clear sky without its disc for the sun at the patch's
centroid (the view's O or S master composite) plus ``E_sun / solid_angle_p`` times the
column, ``E_sun`` = ``--dni`` (800 W/m^2 by default). Prints the worst and the median.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def errors(build_dir: Path, dni_w_m2: float) -> dict:
    from bake.compact_reader import CompactReader
    from bake.evaluate import Build
    from daylit import sky as skies
    from daylit.stackio import read_stack_exr

    build = Build(build_dir)
    view = build.manifest["views"][0]
    lights = build.manifest["dome"]["lights"]
    out = {}
    for stack, entry in view["sun_bounce"].items():
        reader = CompactReader(build.dir, entry["compact"], (view["height"], view["width"]))
        master = read_stack_exr(build.dir / entry["master"])  # (H, W, n, 3)
        base = read_stack_exr(build.dir / view["stacks"][stack]["master"])
        valid = np.any(base != 0.0, axis=(2, 3))  # (H, W): pixels that see a surface
        own, shown = [], []
        for p in build.selection.selectable.tolist():
            c = np.asarray(lights[p]["centroid"], dtype=np.float64)
            el_deg = float(np.degrees(np.arcsin(c[1])))
            if el_deg < 2.0:
                continue
            az_deg = float(np.degrees(np.arctan2(c[0], -c[2])) % 360.0)
            r = skies.patch_mean_radiance(skies.clear_sky(az_deg, el_deg), build.dome_vertices,
                                          include_sun=False)
            weight = dni_w_m2 / build.solid_angles[p]
            decoded = reader.lights([p])[p][valid]
            reader.forget_lights()
            column = master[:, :, p][valid]
            sky = np.einsum("hwnc,nc->hwc", base, r)[valid]
            rms = np.sqrt(((decoded - column) ** 2).mean())
            lit = np.any(column != 0.0, axis=1)
            own.append(np.sqrt(((decoded - column)[lit] ** 2).mean()) / column[lit].mean())
            shown.append(rms * weight / (sky + column * weight).mean())
        out[stack] = {"columns": len(own), "own_max": max(own), "own_median": np.median(own),
                      "displayed_max": max(shown), "displayed_median": np.median(shown)}
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--dni", type=float, default=800.0, help="E_sun, W/m^2")
    args = parser.parse_args()
    for stack, e in errors(args.build, args.dni).items():
        print(f"{stack}: {e['columns']} columns; against its own mean worst "
              f"{100 * e['own_max']:.2f} %, median {100 * e['own_median']:.2f} %; as displayed "
              f"worst {100 * e['displayed_max']:.2f} %, median {100 * e['displayed_median']:.2f} %")

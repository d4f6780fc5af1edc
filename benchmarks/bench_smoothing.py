"""The bounce smoothing on a large site's atlas, label by label against groups of labels, in
the same run (issue 20): builds a site's atlases (the receivers stage of a bake), then smooths
random values of ``--lights`` lights within the surface labels of one atlas with the local
linear fit the bake uses, one label at a time in its bounding box
(:func:`bake.denoise.smooth_label_by_label`, the code before the groups) and by
:func:`bake.denoise.smooth_within_labels` (groups of labels, :mod:`bake.labelgroups`),
alternately, ``--repeat`` times each; prints CPU seconds, and how many values differ and by
how much.

Usage::

    .venv/bin/python benchmarks/bench_smoothing.py SCENE [--atlas lightmap] [--lights 1]

(The palace: ``python scenes/palace/make_site.py OUT`` first.) Tests never assert on time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bake import denoise  # noqa: E402
from bake.dome import Dome  # noqa: E402
from bake.irradiance import SceneSet  # noqa: E402
from bake.pipeline import _atlases, _site_geometry  # noqa: E402
from bake.scene import load_site  # noqa: E402
from bake.writers import BOUNCE_SIGMA_TEXELS  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--atlas", default="lightmap")
    parser.add_argument("--lights", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    site = load_site(args.scene, lights=40, quality="draft")
    dome = Dome.for_light_count(site.settings.lights)
    geometry = _site_geometry(site)
    atlases = _atlases(site, dome, geometry, SceneSet.build(geometry, site.ground.albedo),
                       lambda *a: None)
    labels = atlases[args.atlas].label_image()
    h, w = labels.shape
    count = len(np.unique(labels[labels >= 0]))
    print(f"{args.atlas}: {w} x {h} texels, {int((labels >= 0).sum())} labelled, {count} labels")
    values = np.random.default_rng(0).uniform(0, 1, (h, w, args.lights, 3)).astype(np.float32)
    runs = {"label by label": denoise.smooth_label_by_label,
            "groups": denoise.smooth_within_labels}
    seconds: dict = {name: [] for name in runs}
    out = {}
    for _ in range(args.repeat):
        for name, smooth in runs.items():
            t0 = time.process_time()
            out[name] = smooth(values, labels, BOUNCE_SIGMA_TEXELS, order=1)
            seconds[name].append(time.process_time() - t0)
    for name, times in seconds.items():
        print(f"  {name:15s} CPU s: " + ", ".join(f"{t:.2f}" for t in times))
    a, b = out["label by label"], out["groups"]
    differ = a != b
    relative = (np.abs(a - b)[differ] / np.abs(a[differ])).max() if differ.any() else 0.0
    print(f"  values differing: {int(differ.sum())} of {a.size}, largest relative {relative:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The bounce smoothing on a site's atlas, timed against a baseline in the same run (issue 20).

Builds a site's atlases (the receivers stage of a bake), then smooths random values of
``--lights`` lights within the surface labels of one atlas with the local linear fit the
bake uses, ``--repeat`` times each, alternately, and prints CPU seconds and how many values
differ and by how much. Two baselines:

- by default, one label at a time in its bounding box
  (:func:`bake.denoise.smooth_label_by_label`, the code before the groups) against
  :func:`bake.denoise.smooth_within_labels` (groups of labels, :mod:`bake.labelgroups`);
- with ``--before CHECKOUT``, the bake's whole smoothing of an atlas stack
  (:func:`bake.writers.smooth_bounce`, its fit weights kept from the first call as a
  stack's blocks of lights keep them; that first call timed apart) by another checkout of
  daylit against this one, each in a child process with its checkout first on its path.

Usage::

    .venv/bin/python benchmarks/bench_smoothing.py SCENE [--atlas lightmap] [--lights 1]
        [--repeat 1] [--site-lights 40] [--quality draft] [--before CHECKOUT]

(The palace: ``python scenes/palace/make_site.py OUT`` first.) Tests never assert on time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def _labels(code: Path, scene: str, atlas: str, site_lights: int, quality: str):
    """The ``atlas``'s surface labels (H, W) as the checkout ``code`` builds them."""
    sys.path.insert(0, str(code))
    from bake.dome import Dome
    from bake.irradiance import SceneSet
    from bake.pipeline import _atlases, _site_geometry
    from bake.scene import load_site

    site = load_site(scene, lights=site_lights, quality=quality)
    dome = Dome.for_light_count(site.settings.lights)
    geometry = _site_geometry(site)
    atlases = _atlases(site, dome, geometry, SceneSet.build(geometry, site.ground.albedo),
                       lambda *a: None)
    return atlases[atlas].label_image()


def _values(labels: np.ndarray, lights: int) -> np.ndarray:
    h, w = labels.shape
    return np.random.default_rng(0).uniform(0, 1, (h, w, lights, 3)).astype(np.float32)


def _child(args) -> int:
    """With ``--child CODE``: time ``smooth_bounce`` of CODE; one JSON line, output saved."""
    labels = _labels(Path(args.child), args.scene, args.atlas, args.site_lights, args.quality)
    from bake.writers import smooth_bounce

    values = _values(labels, args.lights)
    plans: dict = {}
    t0 = time.process_time()
    out = smooth_bounce(values, labels, None, plans)
    first = time.process_time() - t0
    seconds = []
    for _ in range(args.repeat):
        t0 = time.process_time()
        out = smooth_bounce(values, labels, None, plans)
        seconds.append(time.process_time() - t0)
    np.save(args.save, out)
    print(json.dumps({"first": first, "seconds": seconds}))
    return 0


def _against_checkout(args) -> int:
    runs = {"before": Path(args.before).resolve(), "this": REPO}
    results: dict = {name: {"first": [], "seconds": []} for name in runs}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            for name, code in runs.items():
                command = [sys.executable, __file__, args.scene, "--atlas", args.atlas,
                           "--lights", str(args.lights), "--repeat", str(args.repeat),
                           "--site-lights", str(args.site_lights), "--quality", args.quality,
                           "--child", str(code), "--save", f"{tmp}/{name}.npy"]
                line = subprocess.run(command, check=True, capture_output=True,
                                      text=True).stdout.strip().splitlines()[-1]
                result = json.loads(line)
                results[name]["first"].append(result["first"])
                results[name]["seconds"].extend(result["seconds"])
        a, b = np.load(f"{tmp}/before.npy"), np.load(f"{tmp}/this.npy")
    print(f"{args.atlas}, {args.lights} lights x RGB, smooth_bounce with kept fit weights:")
    for name, result in results.items():
        print(f"  {name:7s} first call CPU s: " + ", ".join(f"{t:.2f}" for t in result["first"])
              + "; then: " + ", ".join(f"{t:.2f}" for t in result["seconds"]))
    scale = float(np.abs(a).max())
    print(f"  values differing: {int((a != b).sum())} of {a.size}, largest difference "
          f"{float(np.abs(a - b).max()):.2e} (largest value {scale:.2f})")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--atlas", default="lightmap")
    parser.add_argument("--lights", type=int, default=1, help="lights smoothed at once")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--site-lights", type=int, default=40,
                        help="the dome the site is loaded with (the atlas's size follows "
                             "the quality, not this)")
    parser.add_argument("--quality", default="draft", choices=("draft", "final"))
    parser.add_argument("--before", help="another checkout of daylit: its smooth_bounce "
                                         "against this one's")
    parser.add_argument("--rounds", type=int, default=1,
                        help="with --before: child processes per checkout, alternately")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--save", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        return _child(args)
    if args.before:
        return _against_checkout(args)
    labels = _labels(REPO, args.scene, args.atlas, args.site_lights, args.quality)
    from bake import denoise
    from bake.writers import BOUNCE_SIGMA_TEXELS

    h, w = labels.shape
    count = len(np.unique(labels[labels >= 0]))
    print(f"{args.atlas}: {w} x {h} texels, {int((labels >= 0).sum())} labelled, {count} labels")
    values = _values(labels, args.lights)
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

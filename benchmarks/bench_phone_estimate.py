"""The phone's own estimate (issue 16, web/src/phoneestimate.js): time per estimate in the
browser, with the picture meter (web/src/picturemeter.js) as the same-run baseline.

Headless Chromium (SwiftShader, tests/web/harness.py's flags) in camera mode on the scene
estimate's test site (tests/server/conftest.py scene_build, baked here at draft quality, or
``--build`` an existing bake), its fake camera playing a Radiance frame of the clear sky from the
phone's eye-height pose (tests/web/phoneframes.py). Timed in the page
(``window.daylit.debug.timePhoneEstimate``): an estimate with the pose held (the video drawn into
the copy, its pixels read, the fit), an estimate after the pose moved (the pool of pixels and
their hemisphere rays made again, then the fit), and a picture meter reading (the video into its
48x27 copy and its 1296 ground rays). Each at the client's copy size (ESTIMATE_SIZE, 384x216) and
at the 192x108 copy it had before 2026-12-06 (``debug.phoneCopySize``), interleaved.

Run (about a minute on the 2-core reference machine; pyradiance is a dev dependency)::

    nice -n 10 .venv/bin/python benchmarks/bench_phone_estimate.py [--build DIR] [--runs 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

# The copy sizes timed: the client's (web/src/phoneestimate.js ESTIMATE_SIZE) and the one
# before it, the same-run comparison.
COPY_SIZES = [(384, 216), (192, 108)]


def bake_test_site(root: Path) -> Path:
    """The scene estimate's test site (tests/sites.py) baked at draft quality under root."""
    from bake.pipeline import bake
    from tests.sites import scene_estimate_site

    scene = scene_estimate_site(root / "scene")
    bake(scene, root / "build", progress=False, log=lambda msg: None)
    return root / "build"


def main() -> None:
    from playwright.sync_api import sync_playwright

    from benchmarks.radiance import SkySpec
    from tests.radiance_frames import camera_frame, render_build_view
    from tests.web.fakecamera import camera_page, orient, write_y4m
    from tests.web.harness import CHROMIUM_FLAGS, chromium_path
    from tests.web.phoneframes import POSES, view_from_three

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", type=Path, help="an existing bake of the test site")
    ap.add_argument("--runs", type=int, default=5, help="timings, each the mean of 5 calls")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="daylit-bench-phone-") as tmp:
        tmp = Path(tmp)
        build = args.build or bake_test_site(tmp)
        lights = json.loads((build / "manifest.json").read_text())["dome"]["count"]
        standpoint, orientation = POSES["eye"]
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS,
                                        headless=True)
            grey = tmp / "grey.y4m"
            write_y4m(grey, np.full((180, 320, 3), 120, np.uint8))
            sky = np.full((lights, 3), 30.0)
            with camera_page(browser, build, grey, sky, query="&sky=phone") as (page, _, _e):
                page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
                orient(page, *orientation)
                pose = page.evaluate("window.daylit.debug.cameraPose()")
            view = view_from_three(pose["matrixWorld"], pose["fovDeg"], 320, 180)
            rendered, _ = render_build_view(
                build, SkySpec("clear", 10, 15, "10.5", 800.0, 80.0), 320, 180, view=view)
            codes, _ = camera_frame(rendered.sun_image, np.random.default_rng(4))
            y4m = tmp / "clear.y4m"
            write_y4m(y4m, codes)
            query = f"&sky=phone&time={rendered.when_unix_s}"
            with camera_page(browser, build, y4m, sky, query=query) as (page, _, errors):
                page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
                orient(page, *orientation)
                runs = {size: [] for size in COPY_SIZES}
                for _ in range(args.runs):
                    for size in COPY_SIZES:
                        assert page.evaluate("(s) => window.daylit.debug.phoneCopySize(s)",
                                             list(size))
                        runs[size].append(page.evaluate(
                            "window.daylit.debug.timePhoneEstimate(5)"))
                assert not errors, errors
            browser.close()
    report = {}
    for size, timed in runs.items():
        med = {k: float(np.median([r[k] for r in timed]))
               for k in ("estimateMs", "unregisteredMs", "newPoseMs", "meterMs")}
        report[f"{size[0]}x{size[1]}"] = {"runs": timed, "median": med}
        print(f"copy {size[0]}x{size[1]}:")
        print(f"  phone estimate, pose held: {med['estimateMs']:.1f} ms "
              f"(pool of {timed[0]['pool']} pixels)")
        print(f"    of which the pose's registration (poseregister.js): "
              f"{med['estimateMs'] - med['unregisteredMs']:.1f} ms "
              f"(without it {med['unregisteredMs']:.1f} ms)")
        print(f"  phone estimate, new pose (pool made again): {med['newPoseMs']:.1f} ms")
        print(f"  picture meter reading (baseline, same run): {med['meterMs']:.2f} ms")
        print(f"  estimate / meter: {med['estimateMs'] / med['meterMs']:.1f}x; share of one "
              f"core at one estimate per 2 s: {med['estimateMs'] / 2000:.1%}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()

"""Benchmark: frame time of the AR mode against the visit mode (issue 17), one run, headless
Chromium + SwiftShader on this machine.

Two pages of the same build, the same light (a clear sky and its sun) and the same
site-relative pose: one in the visit, one in an AR session under IWER's emulated Meta Quest 3
(tests/web/xremu.py: one eye drawn, a floor-plane hit test; the site placed 23 m ahead by a
select). Each page draws frames back to back with a 1-pixel read after each (the only way to
wait for SwiftShader); the two are interleaved A/B for --rounds rounds and the medians
reported, because the machine is shared. The AR frame is drawn through three.js's WebXR path
(the XR camera of the session's last pose, into the session's framebuffer) with the AR
materials (passthrough: no sky, no ground, real objects depth-only, shadows as alpha).

What it means: SwiftShader is a CPU rasteriser, so the figures compare the two modes' work
on one machine; they are not a phone's or a headset's frame times. IWER's Quest 3 offers two
views even with stereo off (the right one 0 px wide), so three.js submits the scene twice in
AR: a real phone's session has one view.

    python benchmarks/bench_ar.py --build build/demo-40-draft [--frames 40] [--rounds 5]
"""

from __future__ import annotations

import argparse
import base64
import json
import statistics
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.web import xremu  # noqa: E402
from tests.web.harness import CHROMIUM_FLAGS, StubServer, chromium_path  # noqa: E402
from tests.web.kioskref import light_message  # noqa: E402

SKY = "clear:235,22"
EXPOSURE = 0.05
POSE = ((0.5, 1.6, 1.0), 20.0, -4.0, 0.0)  # as tests/web/test_web_ar.py's first pose


def light(build):
    """The sky vector (n, 3) and the sun of SKY, as the benchmark of the web client draws them."""
    from bake.evaluate import Build
    from daylit import sky as skies

    ref = Build(build)
    azimuth_deg, elevation_deg = (float(v) for v in SKY.split(":")[1].split(","))
    clear = skies.clear_sky(azimuth_deg, elevation_deg)
    r = skies.patch_mean_radiance(clear, ref.dome_vertices, include_sun=False)
    sun = {"direction": skies.direction_from_azimuth_elevation(azimuth_deg,
                                                               elevation_deg).tolist(),
           "normalIrradiance": clear.sun.normal_irradiance.tolist()}
    return r, sun


def screen(page, render):
    s = page.evaluate(f"window.daylit.debug.screen({str(render).lower()})")
    return np.frombuffer(base64.b64decode(s["data"]), np.uint8).reshape(s["height"], s["width"], 4)


def open_page(browser, url, size, r, sun, ar):
    ctx = browser.new_context(viewport={"width": size[0], "height": size[1]})
    page = ctx.new_page()
    if ar:
        page.add_init_script(xremu.init_script())
    page.goto(url)
    page.wait_for_function("window.daylit.status.ready", timeout=180000)
    page.evaluate("([r, s]) => window.daylit.debug.relight(r, 1, s)", [r.ravel().tolist(), sun])
    return ctx, page


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--build", type=Path, default=REPO / "build" / "demo-40-draft")
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", default="960x540")
    args = parser.parse_args()
    if not (args.build / "manifest.json").is_file():
        sys.exit(f"{args.build}: no build; bake one: daylit bake scenes/demo -o {args.build} "
                 "--lights 40 --quality draft")
    size = tuple(int(v) for v in args.size.split("x"))
    r, sun = light(args.build)
    position, yaw, pitch, roll = POSE
    pose = xremu.pose_m(position, xremu.rotation(yaw, pitch, roll))
    hit = xremu.floor_hit_m(pose)
    eye = xremu.left_eye_m(pose)
    times = {"visit": [], "ar": []}
    from playwright.sync_api import sync_playwright

    with StubServer(args.build) as server, sync_playwright() as p:
        server.push(light_message(r, 1), remember=True)
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS)
        url = f"{server.url}/?mode=visit&test&exposure={EXPOSURE}"
        try:
            ar_ctx, ar = open_page(browser, url, size, r, sun, ar=True)
            ar.evaluate("localStorage.removeItem('daylit.alignment.xr')")
            ar.locator('[data-mode="ar"]').click()
            ar.wait_for_function("window.daylit.status.mode === 'ar'", timeout=60000)
            ar.evaluate("([p, q]) => { window.__xr.position.set(...p);"
                        " window.__xr.quaternion.set(...q); }",
                        [list(position), xremu.quaternion(pose[:3, :3])])
            ar.wait_for_function("window.daylit.debug.xrState().reticleVisible", timeout=60000)
            ar.evaluate("window.__xr.controllers.right.updateButtonValue('trigger', 1)")
            ar.wait_for_function("(n) => window.daylit.debug.xrState().frames > n", arg=(
                ar.evaluate("window.daylit.debug.xrState().frames") + 3), timeout=60000)
            ar.evaluate("window.__xr.controllers.right.updateButtonValue('trigger', 0)")
            ar.wait_for_function(f"Math.abs(window.daylit.debug.xrState().alignment.position[2]"
                                 f" - {hit[2]}) < 1e-3", timeout=60000)
            print("AR session placed", flush=True)
            visit_ctx, visit = open_page(browser, url, size, r, sun, ar=False)
            site_from_eye = np.linalg.inv(xremu.pose_m(hit, np.eye(3))) @ eye
            visit.evaluate("([m, fov]) => window.daylit.debug.setCameraMatrix(m, fov)",
                           [xremu.column_major(site_from_eye), float(np.degrees(xremu.FOVY_RAD))])
            # The two pictures agree (else the timings compare different work).
            a, v = screen(ar, render=True), screen(visit, render=True)
            hall = a[..., 3] == 255
            agree = np.abs(a[..., :3].astype(int) - v[..., :3].astype(int))[hall].mean()
            timing = f"window.daylit.debug.timeFrames({args.frames})"
            for i in range(args.rounds):
                times["visit"].append(visit.evaluate(timing))
                times["ar"].append(ar.evaluate(timing))
                print(f"round {i + 1}: visit {times['visit'][-1]:.1f} ms, "
                      f"AR {times['ar'][-1]:.1f} ms", flush=True)
            ar_ctx.close()
            visit_ctx.close()
        finally:
            browser.close()
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"\nAR against visit, headless Chromium + SwiftShader, {size[0]}x{size[1]}, "
          f"{args.frames} frames x {args.rounds} rounds (medians), {args.build.name}")
    print(f"  visit {med['visit']:.2f} ms/frame, AR (emulated Quest 3) {med['ar']:.2f} ms/frame, "
          f"ratio {med['ar'] / med['visit']:.2f}")
    print(f"  the hall covers {hall.mean():.1%} of the AR frame; there the two frames differ "
          f"by {agree:.3f} codes on average")
    out = REPO / "bench-results"
    out.mkdir(exist_ok=True)
    (out / "ar.json").write_text(json.dumps({"times_ms": times, "median_ms": med,
                                             "hall_share": float(hall.mean()),
                                             "mean_abs_diff_codes": float(agree)}, indent=1))
    print(f"  raw figures: {out / 'ar.json'}")


if __name__ == "__main__":
    main()

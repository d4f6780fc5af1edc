"""The phone's own estimate with a wrong pose (issue 16, web/src/phoneestimate.js): what a
compass that is off, a tilt that is off or a standpoint chosen a few metres off costs the sun
and the sky it reads.

The scene estimate's test site (tests/sites.py, baked here at draft quality, or ``--build`` an
existing bake) rendered by Radiance (gendaylit clear and intermediate skies on 15 October,
rtrace without the ambient cache: tests/radiance_frames.py, not daylit's tracer) from the pose
camera mode takes at eye height (tests/web/phoneframes.py POSES["eye"]), through the camera
model (noise, sRGB, JPEG) into Chromium's fake camera. The client in camera mode
(``?sky=phone``) is then told a pose off the true one: its compass heading (deviceorientation
alpha), its tilt (beta) or its standpoint moved. For each, the median of four estimates: the
sun's normal and the sky's horizontal irradiance through the render's exposure (known to the
benchmark, not to the phone) against gendaylit's DNI and DHI, and the sun/sky ratio against
the truth's, with the estimate's pose registration on the picture (web/src/poseregister.js)
and, the same-run baseline, without it; the true pose is the other baseline.

Run (about 15 minutes on the 2-core reference machine; pyradiance is a dev dependency)::

    nice -n 10 .venv/bin/python benchmarks/bench_phone_pose.py [--build DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

RENDER = (320, 180)  # the camera's picture; the page is twice that (same aspect)
LUMA = np.array([0.2126, 0.7152, 0.0722])
# (name, local standard time, DNI, DHI): the phone test's clear and intermediate skies
SKIES = [("clear", "10.5", 800.0, 80.0), ("intermediate", "13.0", 400.0, 200.0)]
# (what is off, heading offset deg, tilt offset deg, standpoint offset m (x east, z south))
ERRORS = [
    ("true pose", 0.0, 0.0, (0.0, 0.0)),
    ("heading +3 deg", 3.0, 0.0, (0.0, 0.0)),
    ("heading -3 deg", -3.0, 0.0, (0.0, 0.0)),
    ("heading +6 deg", 6.0, 0.0, (0.0, 0.0)),
    ("heading -6 deg", -6.0, 0.0, (0.0, 0.0)),
    ("heading +10 deg", 10.0, 0.0, (0.0, 0.0)),
    ("heading -10 deg", -10.0, 0.0, (0.0, 0.0)),
    ("tilt +3 deg", 0.0, 3.0, (0.0, 0.0)),
    ("tilt -3 deg", 0.0, -3.0, (0.0, 0.0)),
    ("standpoint 1 m east", 0.0, 0.0, (1.0, 0.0)),
    ("standpoint 3 m east", 0.0, 0.0, (3.0, 0.0)),
    ("standpoint 3 m back", 0.0, 0.0, (0.0, -3.0)),
]
ESTIMATES = 5  # the first is dropped: the sky's isotropic share is followed across estimates


def _render(build: Path, browser, tmp: Path) -> list[dict]:
    """Per sky: the render (tests.radiance_frames.RenderedSky), its fake camera file, its
    exposure (linear units per W/(m^2 sr)), from the pose the page takes for POSES["eye"]."""
    from benchmarks.radiance import SkySpec
    from tests.radiance_frames import ACCURATE_CAMERA_RAYS, camera_frame, render_build_view
    from tests.web.fakecamera import camera_page, orient, write_y4m
    from tests.web.phoneframes import POSES, view_from_three

    lights = json.loads((build / "manifest.json").read_text())["dome"]["count"]
    standpoint, orientation = POSES["eye"]
    grey = tmp / "grey.y4m"
    write_y4m(grey, np.full((RENDER[1], RENDER[0], 3), 120, np.uint8))
    with camera_page(browser, build, grey, np.full((lights, 3), 30.0), query="&sky=phone",
                     size=(2 * RENDER[0], 2 * RENDER[1])) as (page, _, _errors):
        page.evaluate("(p) => window.daylit.debug.standAt(p)", standpoint)
        orient(page, *orientation)
        pose = page.evaluate("window.daylit.debug.cameraPose()")
    view = view_from_three(pose["matrixWorld"], pose["fovDeg"], *RENDER)
    rng = np.random.default_rng(4)
    out = []
    for name, hour, dni, dhi in SKIES:
        print(f"rendering the {name} sky with Radiance...", flush=True)
        rendered, _ = render_build_view(build, SkySpec(name, 10, 15, hour, dni, dhi), *RENDER,
                                        view=view, rays=ACCURATE_CAMERA_RAYS)
        codes, exposure = camera_frame(rendered.sun_image, rng)
        y4m = tmp / f"{name}.y4m"
        write_y4m(y4m, codes)
        out.append({"name": name, "rendered": rendered, "y4m": y4m, "exposure": exposure,
                    "pose": pose})
    return out


def _measure(build: Path, browser, sky: dict) -> list[dict]:
    """The client's estimate under each pose error of ERRORS, for one rendered sky, with the
    pose registration on and off (the same page, the same frames)."""
    from tests.web.fakecamera import camera_page

    lights = json.loads((build / "manifest.json").read_text())["dome"]["count"]
    query = f"&sky=phone&time={sky['rendered'].when_unix_s}"
    rows = []
    with camera_page(browser, build, sky["y4m"], np.full((lights, 3), 30.0), query=query,
                     size=(2 * RENDER[0], 2 * RENDER[1])) as (page, _, errors):
        for registered in (True, False):
            page.evaluate("(on) => window.daylit.debug.registerPose(on)", registered)
            for error in ERRORS:
                rows.append({"registered": registered, **_estimate(page, sky, *error)})
        assert not errors, errors
    return rows


def _estimate(page, sky: dict, label: str, d_heading: float, d_tilt: float,
              offset_m: tuple[float, float]) -> dict:
    """The median of four estimates with the phone told a pose off by these: its errors
    against the render's truth (fractions), pixels used, inlier share, the last registration
    shift, and where the drawn overlay ends (the registration turns the view: camera-view.js
    turnBy) against the true pose, pixels of the estimate's copy."""
    from tests.web.fakecamera import orient
    from tests.web.phoneframes import POSES, copy_shift_px

    standpoint, (alpha, beta, gamma) = POSES["eye"]
    rendered = sky["rendered"]
    # Only the benchmark's estimates, each error from the alignment the visitor left (the
    # registration's turns of the error before gone).
    page.evaluate("window.daylit.debug.holdPhoneEstimates(true)")
    page.evaluate("window.daylit.debug.resetAlignment()")
    # deviceorientation alpha grows counter-clockwise seen from above: a compass reading
    # more than the truth turns the drawn view to the left
    page.evaluate("(p) => window.daylit.debug.standAt(p)",
                  [standpoint[0] + offset_m[0], standpoint[1], standpoint[2] + offset_m[1]])
    orient(page, alpha + d_heading, beta + d_tilt, gamma)
    ests = [page.evaluate("window.daylit.debug.phoneEstimate()") for _ in range(ESTIMATES)][1:]
    overlay = page.evaluate("window.daylit.debug.cameraPose()")
    if any(e is None for e in ests):
        return {"error": label, "none": True}
    sun, sky_h = (float(np.median([LUMA @ np.asarray(e[key]) for e in ests])) / sky["exposure"]
                  for key in ("sunNormal", "skyHorizontal"))
    ratio = float(np.median([e["ratio"] for e in ests]))
    return {"error": label,
            "sun": sun / rendered.dni_w_m2 - 1.0,
            "sky": sky_h / rendered.dhi_w_m2 - 1.0,
            "ratio": ratio / (rendered.dni_w_m2 / rendered.dhi_w_m2) - 1.0,
            "used": int(np.median([e["used"] for e in ests])),
            "inliers": float(np.median([e["inlierFraction"] for e in ests])),
            "shift": ests[-1]["shiftPx"],
            # a standpoint error is not a turn: its residual is not the overlay's whole error
            "overlay_px": float(np.hypot(*copy_shift_px(sky["pose"], overlay)))}


def main() -> None:
    from playwright.sync_api import sync_playwright

    from benchmarks.bench_phone_estimate import bake_test_site
    from tests.web.harness import CHROMIUM_FLAGS, chromium_path

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", type=Path, help="an existing bake of the test site")
    ap.add_argument("--json", type=Path, help="write the rows here too")
    args = ap.parse_args()
    results = {}
    with tempfile.TemporaryDirectory(prefix="daylit-bench-pose-") as tmp:
        tmp = Path(tmp)
        build = args.build or bake_test_site(tmp)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS,
                                        headless=True)
            for sky in _render(build, browser, tmp):
                results[sky["name"]] = _measure(build, browser, sky)
            browser.close()
    print("\nthe phone's estimate against gendaylit (sun: DNI, sky: DHI, ratio: DNI/DHI);"
          " the true pose first (the same-run baseline)")
    print(f"{'sky':<13} {'registered':<11} {'pose error':<22} {'sun':>7} {'sky':>7} {'ratio':>7}"
          f" {'used':>5} {'inliers':>8} {'shift px':>9} {'overlay px':>10}")
    for name, rows in results.items():
        for r in rows:
            head = f"{name:<13} {'yes' if r['registered'] else 'no':<11} {r['error']:<22}"
            if r.get("none"):
                print(f"{head} no estimate")
                continue
            print(f"{head} {r['sun']:>+7.1%} {r['sky']:>+7.1%}"
                  f" {r['ratio']:>+7.1%} {r['used']:>5d} {r['inliers']:>8.2f}"
                  f" {r['shift'][0]:>+4d},{r['shift'][1]:>+4d} {r['overlay_px']:>10.1f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

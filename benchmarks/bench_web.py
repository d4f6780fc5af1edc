"""Benchmark of the web client (issue 5) in headless Chromium (SwiftShader WebGL2) on this
machine, in one run with same-run baselines:

1. frame time of the demo relit by daylit, the sun drawn with its shadow maps (docs/sun.md),
   against the same meshes drawn the ordinary three.js way (MeshStandardMaterial, a
   DirectionalLight with a 2048^2 PCF shadow map, a HemisphereLight): goal ratio <= 1.2; and
   daylit's frame with the sun switched off (no shadow-map reads), to show the sun's cost;
2. frame time with 40 against 400 lights: goal ratio <= 1.05 (frames only sample the relit
   targets);
3. relight-pass time against the number of lights and, per stack, against k (layers);
4. bytes transferred and time until the first relit frame on loopback through `daylit serve`.

Builds: the demo at draft quality with 40 and 400 lights in build/demo-40-draft and
build/demo-400-draft, baked here when missing (the 400-light bake takes several minutes).

    .venv/bin/python benchmarks/bench_web.py [--frames 60] [--size 960x540]

Frame times are CPU+GPU per frame, drawn back to back with a 1-pixel read after each (the
only way to wait for SwiftShader's GPU); measurements are interleaved A/B/A/B and the medians
reported, because the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.web.harness import CHROMIUM_FLAGS, DaylitServer, chromium_path  # noqa: E402

SKY = "clear:235,22"


def ensure_build(lights: int) -> Path:
    out = REPO / "build" / f"demo-{lights}-draft"
    if not (out / "manifest.json").exists():
        print(f"baking the demo with {lights} lights at draft quality into {out} ...",
              flush=True)
        subprocess.run([str(REPO / ".venv" / "bin" / "daylit"), "bake", "scenes/demo", "-o",
                        str(out), "--lights", str(lights), "--quality", "draft",
                        "--no-progress"], cwd=REPO, check=True)
    return out


def replay_dir() -> Path:
    from tests.web.test_web_e2e import fisheye

    d = Path(tempfile.mkdtemp(prefix="daylit-bench-sky-"))
    cv2.imwrite(str(d / "a.png"), fisheye(sky_code=110, sun=(235, 22)))
    return d


def first_load(browser, build: Path, sky_dir: Path, size) -> dict:
    """Bytes and time to the first relit frame of a fresh page, alone on the machine's GPU
    (the other pages are opened only afterwards)."""
    with DaylitServer(build, "--sky", f"replay:{sky_dir}") as server:
        ctx = browser.new_context(viewport={"width": size[0], "height": size[1]})
        page = ctx.new_page()
        page.goto(f"{server.url}/?mode=visit&exposure=0.02")
        page.wait_for_function("window.daylit.status.exactRelitMs !== null", timeout=180000)
        out = {
            "first_relit_ms": page.evaluate("window.daylit.status.exactRelitMs"),
            "bytes_loaded": page.evaluate("window.daylit.status.bytesLoaded"),
            "bytes_transferred": page.evaluate("""performance.getEntriesByType('resource')
                .reduce((s, e) => s + (e.transferSize || 0), 0)"""),
        }
        ctx.close()
    return out


class Subject:
    """One build served by `daylit serve` and open in its own page, ready to be timed."""

    def __init__(self, browser, build: Path, sky_dir: Path, size):
        from bake.evaluate import Build

        self.ref = Build(build)
        self.server = DaylitServer(build, "--sky", f"replay:{sky_dir}").start()
        self.ctx = browser.new_context(viewport={"width": size[0], "height": size[1]})
        page = self.page = self.ctx.new_page()
        page.goto(f"{self.server.url}/?mode=visit&test&exposure=0.02")
        page.wait_for_function("window.daylit.status.ready && window.daylit.status.lightsExact"
                               " && window.daylit.status.exactRelitMs !== null", timeout=180000)
        from daylit import sky as skies

        azimuth_deg, elevation_deg = (float(v) for v in SKY.split(":")[1].split(","))
        clear = skies.clear_sky(azimuth_deg, elevation_deg)
        self.sky = skies.patch_mean_radiance(clear, self.ref.dome_vertices, include_sun=False)
        self.sun = {
            "direction": skies.direction_from_azimuth_elevation(azimuth_deg,
                                                                elevation_deg).tolist(),
            "normalIrradiance": clear.sun.normal_irradiance.tolist(),
        }
        self.set_sun(True)  # and stop the stream
        # The hull planes too (fetched on demand in hull-plane mode), so that every atlas stack
        # is timed; the frames below stay in lightmap mode, where they are not drawn.
        page.evaluate("window.daylit.debug.activateAll()")
        page.evaluate("window.daylit.debug.setCamera([55, 28, 70], [0, 2, 0])")
        self.ours, self.no_sun, self.standard, self.relight = [], [], [], []
        self.stacks: dict[str, list[dict]] = {}

    def set_sun(self, on: bool) -> None:
        self.page.evaluate("([r, s]) => window.daylit.debug.relight(r, 1, s)",
                           [self.sky.ravel().tolist(), self.sun if on else None])

    def frames(self, n: int, variant: str) -> None:
        """variant: "daylit" (with the sun), "no sun" or "standard" (plain three.js)."""
        standard = variant == "standard"
        if variant == "no sun":
            self.set_sun(False)
        self.page.evaluate(f"window.daylit.debug.useStandardMaterials({str(standard).lower()})")
        ms = self.page.evaluate(f"window.daylit.debug.timeFrames({n})")
        {"daylit": self.ours, "no sun": self.no_sun, "standard": self.standard}[variant].append(ms)
        self.page.evaluate("window.daylit.debug.useStandardMaterials(false)")
        if variant == "no sun":
            self.set_sun(True)

    def relight_pass(self) -> None:
        self.relight.append(self.page.evaluate("window.daylit.debug.timeRelight(6)"))
        for key in self.page.evaluate("window.daylit.debug.stacks()"):
            s = self.page.evaluate(f"window.daylit.debug.timeRelightStack('{key}', 6)")
            self.stacks.setdefault(key, []).append(s)

    def result(self) -> dict:
        stacks = {key: {**runs[0], "ms": statistics.median(r["ms"] for r in runs),
                        "sync_ms": statistics.median(r["syncMs"] for r in runs)}
                  for key, runs in self.stacks.items()}
        return {
            "lights": self.ref.light_count,
            "frame_ms": statistics.median(self.ours), "frame_ms_all": self.ours,
            "no_sun_ms": statistics.median(self.no_sun), "no_sun_ms_all": self.no_sun,
            "standard_ms": statistics.median(self.standard), "standard_ms_all": self.standard,
            "relight_ms": statistics.median(self.relight), "relight_ms_all": self.relight,
            "stacks": stacks,
        }

    def close(self) -> None:
        self.ctx.close()
        self.server.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", default="960x540")
    parser.add_argument("--lights", type=int, nargs="+", default=[40, 400],
                        help="dome sizes to compare (default: 40 400; the first is the base)")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    builds = {n: ensure_build(n) for n in args.lights}
    sky_dir = replay_dir()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS)
        loads = {n: first_load(browser, build, sky_dir, size) for n, build in builds.items()}
        subjects = {}
        try:
            for n, build in builds.items():  # one after the other: first-frame times alone
                subjects[n] = Subject(browser, build, sky_dir, size)
            # Interleaved, so that the shared machine's load hits every variant alike.
            for _ in range(args.rounds):
                for variant in ("daylit", "no sun", "standard"):
                    for subject in subjects.values():
                        subject.frames(args.frames, variant)
                for subject in subjects.values():
                    subject.relight_pass()
            results = {n: {**subject.result(), **loads[n]} for n, subject in subjects.items()}
        finally:
            for subject in subjects.values():
                subject.close()
            browser.close()
    a, b = results[args.lights[0]], results[args.lights[-1]]
    print(f"\nweb client, headless Chromium + SwiftShader, {size[0]}x{size[1]}, "
          f"{args.frames} frames x {args.rounds} rounds (medians)")
    for n, res in results.items():
        print(f"  {n:4d} lights: daylit {res['frame_ms']:.2f} ms/frame (sun and its shadows), "
              f"{res['no_sun_ms']:.2f} without the sun, three.js standard "
              f"{res['standard_ms']:.2f} ms/frame, ratio {res['frame_ms'] / res['standard_ms']:.2f}"
              f" (goal <= 1.2)")
    print(f"  frame time 400 / 40 lights: {b['frame_ms'] / a['frame_ms']:.3f} (goal <= 1.05); "
          f"the same ratio for the standard scene, identical work: "
          f"{b['standard_ms'] / a['standard_ms']:.3f} (the noise)")
    print(f"  relight pass: {a['relight_ms']:.1f} ms at 40 lights, {b['relight_ms']:.1f} ms at "
          f"400 (ratio {b['relight_ms'] / a['relight_ms']:.2f})")
    print("  (relight times are passes drawn back to back, less one wait for the GPU: one pass "
          "and its wait take "
          f"{statistics.median(s['sync_ms'] for s in b['stacks'].values()):.0f} ms)")
    print("  relight per stack (ms, layers = k + refinements, selected-light slots, texels):")
    for n, res in results.items():
        for key, s in res["stacks"].items():
            per = s["ms"] / ((s["layers"] + s["slots"]) * s["texels"] / 1e6)
            print(f"    {n:4d} {key:12s} {s['ms']:7.2f} ms  k {s['k']:3d}  layers "
                  f"{s['layers']:3d}  slots {s['slots']}  {s['texels']:7d} texels  "
                  f"{per:6.2f} ms per layer-Mtexel")
    for n, res in results.items():
        print(f"  {n:4d} lights: {res['bytes_loaded'] / 1e6:.2f} MB loaded "
              f"({res['bytes_transferred'] / 1e6:.2f} MB on the wire), first relit frame "
              f"{res['first_relit_ms'] / 1000:.2f} s after navigation (loopback)")
    out = REPO / "bench-results"
    out.mkdir(exist_ok=True)
    (out / "web.json").write_text(json.dumps(results, indent=1))
    print(f"  raw figures: {out / 'web.json'}")


if __name__ == "__main__":
    main()

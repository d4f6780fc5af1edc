"""Benchmark of the web client (issue 5) in headless Chromium (SwiftShader WebGL2) on this
machine, in one run with same-run baselines:

1. frame time of the demo relit by daylit against the same meshes drawn the ordinary three.js
   way (MeshStandardMaterial, a DirectionalLight with a 2048^2 PCF shadow map, a
   HemisphereLight): goal ratio <= 1.2;
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


def measure(browser, build: Path, sky_dir: Path, size, frames: int, rounds: int) -> dict:
    from bake.evaluate import Build

    ref = Build(build)
    r = ref.light_vector(SKY).astype("float32").ravel().tolist()
    with DaylitServer(build, "--sky", f"replay:{sky_dir}") as server:
        ctx = browser.new_context(viewport={"width": size[0], "height": size[1]})
        page = ctx.new_page()
        page.goto(f"{server.url}/?mode=visit&test&exposure=0.02")
        page.wait_for_function("window.daylit.status.ready && window.daylit.status.lightsExact"
                               " && window.daylit.status.firstRelitMs !== null", timeout=120000)
        first = page.evaluate("window.daylit.status.firstRelitMs")
        loaded = page.evaluate("window.daylit.status.bytesLoaded")
        transfer = page.evaluate("""performance.getEntriesByType('resource')
            .reduce((s, e) => s + (e.transferSize || 0), 0)""")
        page.evaluate("(r) => window.daylit.debug.relight(r, 1)", r)
        page.evaluate("window.daylit.debug.setCamera([55, 28, 70], [0, 2, 0])")
        ours, standard = [], []
        for _ in range(rounds):
            ours.append(page.evaluate(f"window.daylit.debug.timeFrames({frames})"))
            page.evaluate("window.daylit.debug.useStandardMaterials(true)")
            standard.append(page.evaluate(f"window.daylit.debug.timeFrames({frames})"))
            page.evaluate("window.daylit.debug.useStandardMaterials(false)")
        relight = [page.evaluate("window.daylit.debug.timeRelight(5)") for _ in range(rounds)]
        stacks = {key: page.evaluate(f"window.daylit.debug.timeRelightStack('{key}', 5)")
                  for key in page.evaluate("window.daylit.debug.stacks()")}
        ctx.close()
    return {
        "lights": ref.light_count,
        "frame_ms": statistics.median(ours), "frame_ms_all": ours,
        "standard_ms": statistics.median(standard), "standard_ms_all": standard,
        "relight_ms": statistics.median(relight), "relight_ms_all": relight,
        "stacks": stacks, "first_relit_ms": first, "bytes_loaded": loaded,
        "bytes_transferred": transfer,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--size", default="960x540")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    builds = {n: ensure_build(n) for n in (40, 400)}
    sky_dir = replay_dir()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS)
        results = {n: measure(browser, b, sky_dir, size, args.frames, args.rounds)
                   for n, b in builds.items()}
        browser.close()
    a, b = results[40], results[400]
    print(f"\nweb client, headless Chromium + SwiftShader, {size[0]}x{size[1]}, "
          f"{args.frames} frames x {args.rounds} rounds (medians)")
    for n, res in results.items():
        print(f"  {n:4d} lights: daylit {res['frame_ms']:.2f} ms/frame, three.js standard "
              f"{res['standard_ms']:.2f} ms/frame, ratio {res['frame_ms'] / res['standard_ms']:.2f}"
              f" (goal <= 1.2)")
    print(f"  frame time 400 / 40 lights: {b['frame_ms'] / a['frame_ms']:.3f} (goal <= 1.05)")
    print(f"  relight pass: {a['relight_ms']:.1f} ms at 40 lights, {b['relight_ms']:.1f} ms at "
          f"400 (ratio {b['relight_ms'] / a['relight_ms']:.2f})")
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

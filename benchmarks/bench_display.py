"""Frame time of the linear HDR frame (web/src/hdr.js: the scene drawn into a half-float
target, the shadowing planes multiplying it there, one tone-map pass), with MSAA 4x (the
default) and without, against the frame drawn straight to the screen as before (?frame=direct:
the shadowing planes on the tone-mapped sRGB picture), in one run, in headless Chromium
(SwiftShader WebGL2), lightmap and hull-plane modes. One page; the variants interleaved round
by round, medians reported (the machine is shared).

    .venv/bin/python benchmarks/bench_display.py BUILD [--frames 40] [--rounds 5] [--size 960x540]

BUILD: a baked build, e.g. the demo at draft quality (build/demo-40-draft).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.web.harness import CHROMIUM_FLAGS, StubServer, chromium_path  # noqa: E402
from tests.web.kioskref import light_message  # noqa: E402

SKY = "clear:235,22"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", default="960x540")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))

    from playwright.sync_api import sync_playwright

    from bake.evaluate import Build

    r = Build(args.build).light_vector(SKY)
    variants = [(shading, frame) for shading in ("lightmap", "hull")
                for frame in ("linear", "linear-1x", "direct")]
    times: dict[tuple[str, str], list[float]] = {v: [] for v in variants}
    with StubServer(args.build) as server, sync_playwright() as p:
        server.push(light_message(r, 1), remember=True)
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_FLAGS)
        page = browser.new_context(viewport={"width": width, "height": height}).new_page()
        page.goto(f"{server.url}/?mode=visit&test&exposure=0.02", wait_until="commit",
                  timeout=180000)
        page.wait_for_function("window.daylit && window.daylit.status.ready "
                               "&& window.daylit.status.lightsExact", timeout=180000)
        page.select_option(".shadingmode", "hull")  # load the hull planes once
        page.wait_for_function("window.daylit.status.shadingMode === 'hull'", timeout=180000)
        for _ in range(args.rounds):
            for shading, frame in variants:
                if page.evaluate("window.daylit.status.shadingMode") != shading:
                    page.select_option(".shadingmode", shading)
                    page.wait_for_function(f"window.daylit.status.shadingMode === '{shading}'")
                page.evaluate("([on, n]) => window.daylit.debug.setLinearFrame(on, n)",
                              [frame != "direct", 0 if frame == "linear-1x" else 4])
                page.evaluate("window.daylit.debug.timeFrames(3)")  # the new path compiled
                linear = page.evaluate("window.daylit.debug.formats()")["linearFrame"]
                assert linear == (frame != "direct"), (shading, frame, linear)
                times[(shading, frame)].append(
                    page.evaluate(f"window.daylit.debug.timeFrames({args.frames})"))
        browser.close()
    print(f"{args.build} at {width}x{height}, {args.rounds} rounds of {args.frames} frames, "
          "median ms per frame:")
    for shading in ("lightmap", "hull"):
        lin = statistics.median(times[(shading, "linear")])
        one = statistics.median(times[(shading, "linear-1x")])
        direct = statistics.median(times[(shading, "direct")])
        print(f"  {shading:8s}: linear HDR MSAA 4x {lin:.1f} ms ({lin / direct:.2f}x), "
              f"no MSAA {one:.1f} ms ({one / direct:.2f}x), direct (before) {direct:.1f} ms")


if __name__ == "__main__":
    main()

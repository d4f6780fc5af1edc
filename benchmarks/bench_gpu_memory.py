"""GPU memory of the web client per device profile and shading mode (issue 17; docs/benchmarks.md,
"GPU memory"): the meter's totals (web/src/gpumemory.js) and its per-allocation breakdown,
named by module (debug.gpuBreakdown), in headless Chromium.

    python benchmarks/bench_gpu_memory.py BUILD [--profiles phone,desktop] [--top 25]
    python benchmarks/bench_gpu_memory.py BUILD --formats astc,exact

``--formats``: the phone's hull-plane mode once per texture mode (`?textures=`) and once with
every array decoded to RGBA8, the exact reference of the same run: the textures' bytes and each
relit target's difference from the reference (RMS, largest and mean, % of the target's mean).

Per profile (phone: 390 x 844 CSS px at device pixel ratio 3 with touch, the client draws 780 x
1688 and takes its phone profile; desktop: 960 x 540 at 1) it opens the visit in lightmap mode
and in hull-plane mode, each with a clear sky without the sun and with it (a version-2 light:
the sun's shadow maps exist only then), and prints textures, renderbuffers, the drawing
buffer's estimate, the total, and hull mode's extra over lightmap mode; then the largest
allocations of the phone's hull mode with the sun. Bytes as the meter counts them (MB = 1e6
bytes).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.web.harness import CHROMIUM_FLAGS, StubServer, chromium_path  # noqa: E402
from tests.web.kioskref import light_message  # noqa: E402

PROFILES = {
    # a phone as Chromium emulates one (touch: the client takes its phone profile)
    "phone": dict(width=390, height=844, dpr=3, mobile=True),
    "desktop": dict(width=960, height=540, dpr=1, mobile=False),
}
SKY = "clear:135,40"

GL_NAMES = {
    0x8058: "RGBA8",
    0x881A: "RGBA16F",
    0x8814: "RGBA32F",
    0x8CAC: "DEPTH32F",
    0x88F0: "DEPTH24_STENCIL8",
    0x81A6: "DEPTH24",
    0x81A5: "DEPTH16",
    0x8229: "R8",
    0x1908: "RGBA",
    0x1903: "RED",
    0x1902: "DEPTH",
    0x9274: "ETC2_RGB8",
    0x9278: "ETC2_RGBA8",
    0x93B0: "ASTC_4x4",
    0x8E8C: "BC7",
    0x8D64: "ETC1",
}


def sun_of(spec: str) -> dict:
    from daylit import sky as skies

    az, el = (float(v) for v in spec.split(":")[1].split(","))
    return {
        "direction": skies.direction_from_azimuth_elevation(az, el).tolist(),
        "normalIrradiance": skies.clear_sky(az, el).sun.normal_irradiance.tolist(),
    }


def new_context(browser, profile: dict):
    """A browser context with the device ``profile``'s viewport (a phone: touch, mobile)."""
    return browser.new_context(
        viewport={"width": profile["width"], "height": profile["height"]},
        device_scale_factor=profile["dpr"],
        is_mobile=profile["mobile"],
        has_touch=profile["mobile"],
    )


def measure(
    browser, server, reference, profile: dict, shading: str, sun: bool, query: str = ""
) -> dict:
    context = new_context(browser, profile)
    page = context.new_page()
    try:
        hull = "&shading=hull" if shading == "hull" else ""
        page.goto(f"{server.url}/?mode=visit&test{hull}{query}")
        page.wait_for_function(
            "window.daylit && window.daylit.status.exactRelitMs !== null", timeout=120000
        )
        if sun:
            from daylit import sky as skies

            r = skies.patch_mean_radiance(
                skies.clear_sky(135, 40), reference.dome_vertices, include_sun=False
            )
            page.evaluate(
                "([r, s]) => window.daylit.debug.relight(r, 2, s)",
                [r.astype(float).ravel().tolist(), sun_of(SKY)],
            )
        # a few frames drawn (the HDR frame is allocated by the first)
        page.evaluate(
            "() => new Promise((ok) => { let n = 0;"
            " const f = () => (++n > 3 ? ok() : requestAnimationFrame(f)); f(); })"
        )
        status = page.evaluate("JSON.parse(JSON.stringify(window.daylit.status))")
        breakdown = page.evaluate("window.daylit.debug.gpuBreakdown()")
    finally:
        context.close()
    t, rb, db = (
        status["gpuTextureBytes"],
        status["gpuRenderbufferBytes"],
        status["gpuDrawingBufferBytes"],
    )
    return {
        "textures": t,
        "renderbuffers": rb,
        "drawing": db,
        "total": t + rb + db,
        "breakdown": breakdown,
    }


def relit_targets(browser, server, profile: dict, query: str) -> tuple[dict, dict]:
    """The phone's hull-plane mode with ``query``: its status and every relit target, (H*W*4,)
    float32 each."""
    import base64

    import numpy as np

    context = new_context(browser, profile)
    page = context.new_page()
    try:
        page.goto(f"{server.url}/?mode=visit&test&shading=hull{query}")
        page.wait_for_function(
            "window.daylit && window.daylit.status.exactRelitMs !== null", timeout=120000
        )
        status = page.evaluate("JSON.parse(JSON.stringify(window.daylit.status))")
        targets = {}
        for key in page.evaluate("window.daylit.debug.targets()"):
            snap = page.evaluate("(k) => window.daylit.debug.snapshot(k)", key)
            targets[key] = np.frombuffer(base64.b64decode(snap["data"]), np.float32)
    finally:
        context.close()
    return status, targets


def compare_formats(browser, server, modes: list[str]) -> None:
    """Print, per texture mode, the textures' bytes and the relit targets' differences from
    the same targets drawn with every array decoded to RGBA8 (``?textures=rgba8``)."""
    import numpy as np

    phone = PROFILES["phone"]
    _, reference = relit_targets(browser, server, phone, "&textures=rgba8")
    print("mode     uastc  etc1s  textures MB  target        RMS %    max %   mean %"
          "  (of the target's mean)")
    for mode in modes:
        status, targets = relit_targets(browser, server, phone, f"&textures={mode}")
        head = (f"{mode:8s} {status['uastcTextures']:6s} {status['etc1sTextures']:6s} "
                f"{mb(status['gpuTextureBytes']):>11s}")
        for key, exact in reference.items():
            exact_rgb = exact.reshape(-1, 4)[:, :3]
            diff = targets[key].reshape(-1, 4)[:, :3] - exact_rgb
            mean = float(np.abs(exact_rgb).mean()) or 1.0
            print(f"{head}  {key:12s} {100 * np.sqrt((diff**2).mean()) / mean:7.3f} "
                  f"{100 * np.abs(diff).max() / mean:8.3f} {100 * diff.mean() / mean:8.3f}")
            head = " " * len(head)


def mb(b: float) -> str:
    return f"{b / 1e6:.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("build", type=Path)
    ap.add_argument("--profiles", default="phone,desktop")
    ap.add_argument("--query", default="", help="extra URL parameters, e.g. '&textures=rgba8'")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--json", type=Path, help="write every figure here")
    ap.add_argument("--formats", help="texture modes to compare with RGBA8, e.g. astc,exact"
                    " (the phone's hull-plane mode; instead of the memory table)")
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    from bake.evaluate import Build

    reference = Build(args.build)
    results = {}
    with StubServer(args.build) as server, sync_playwright() as p:
        server.push(light_message(reference.light_vector(SKY), 1), remember=True)
        browser = p.chromium.launch(
            executable_path=chromium_path(), args=CHROMIUM_FLAGS, headless=True
        )
        if args.formats:
            compare_formats(browser, server, args.formats.split(","))
            browser.close()
            return
        print(
            "profile  sun  mode      textures  renderbuf  drawing(est)  total    hull extra   (MB)"
        )
        for name in args.profiles.split(","):
            for sun in (False, True):
                row = {}
                for shading in ("lightmap", "hull"):
                    row[shading] = measure(
                        browser, server, reference, PROFILES[name], shading, sun, args.query
                    )
                    m = row[shading]
                    extra = mb(m["total"] - row["lightmap"]["total"]) if shading == "hull" else ""
                    print(
                        f"{name:8s} {'yes' if sun else 'no':4s} {shading:9s} "
                        f"{mb(m['textures']):>8s} {mb(m['renderbuffers']):>10s} "
                        f"{mb(m['drawing']):>12s} {mb(m['total']):>7s} {extra:>11s}"
                    )
                results[f"{name}/{'sun' if sun else 'nosun'}"] = row
        browser.close()
    worst = results.get("phone/sun", next(iter(results.values())))["hull"]["breakdown"]
    print(
        f"\nlargest allocations, {'phone' if 'phone/sun' in results else ''}"
        " hull mode with the sun:"
    )
    for a in worst[: args.top]:
        fmt = GL_NAMES.get(a.get("format"), hex(a.get("format") or 0))
        shape = f"{a.get('w')}x{a.get('h')}x{a.get('d')}"
        print(
            f"  {mb(a['bytes']):>6s} MB  {a['name']:32s} {fmt:10s} {shape}"
            f" samples={a.get('samples', '-')}"
        )
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
